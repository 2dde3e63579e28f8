// The flat field's accumulation (flatfield.hpp) and its binding.
#include "flatfield.hpp"

#include <cmath>
#include <limits>
#include <vector>

#include "arrays.hpp"
#include "stages.hpp"

namespace tactiled {

double accumulate(double* ata, double* atb, const double* resid_op, const double* m,
                  const double* jx, const double* jy, const double* r, const double* u,
                  const long long* idx, long long k, double w) {
    std::vector<double> c(3 * k);
    double check = 0.0;
    for (long long i = 0; i < k; ++i) {
        c[i] = -m[i];
        c[k + i] = jx[i];
        c[2 * k + i] = jy[i];
    }
    std::vector<double> eu(k);
    for (long long i = 0; i < k; ++i) {
        eu[i] = c[i] * u[idx[i]] + c[k + i] * u[idx[k + i]] + c[2 * k + i] * u[idx[2 * k + i]];
        check += c[i] + c[k + i] + c[2 * k + i];
    }
    std::vector<double> r0(k);
    double total = 0.0, trace = 0.0;
    for (long long i = 0; i < k; ++i) {
        double acc = r[i];
        for (long long j = 0; j < k; ++j) {
            acc += resid_op[i * k + j] * eu[j];
            check += resid_op[i * k + j];
        }
        r0[i] = acc;
        total += acc * acc;
        trace += resid_op[i * k + i];
    }
    if (!std::isfinite(check + total)) return std::numeric_limits<double>::quiet_NaN();
    const long long n3 = 3 * k;
    for (int a = 0; a < 3; ++a)
        for (long long i = 0; i < k; ++i) {
            const double ci = w * c[a * k + i];
            atb[a * k + i] += ci * r0[i];
            for (int b = 0; b < 3; ++b)
                for (long long j = 0; j < k; ++j)
                    ata[(a * k + i) * n3 + b * k + j] += ci * resid_op[i * k + j] * c[b * k + j];
        }
    return total - trace;
}

void bind_flatfield(py::module_& m) {
    m.def("accumulate",
          [](py::array_t<double, py::array::c_style> ata, py::array_t<double, py::array::c_style> atb,
             Arr resid_op, Arr mm, Arr jx, Arr jy, Arr r, Arr u, IArr idx, double w) {
              const long long k = mm.size();
              if (ata.size() != 9 * k * k || atb.size() != 3 * k || resid_op.size() != k * k ||
                  jx.size() != k || jy.size() != k || r.size() != k || idx.size() != 3 * k)
                  throw py::value_error("accumulate: sums of 3k, an operator of k x k and 3k indices needed");
              for (long long i = 0; i < 3 * k; ++i)
                  if (idx.data()[i] < 0 || idx.data()[i] >= u.size()) throw py::index_error("accumulate: idx outside u");
              return accumulate(ata.mutable_data(), atb.mutable_data(), resid_op.data(), mm.data(),
                                jx.data(), jy.data(), r.data(), u.data(), idx.data(), k, w);
          },
          "tactiled.fit.flatfield._accumulate: ata and atb are updated in place.");
}
}  // namespace tactiled
