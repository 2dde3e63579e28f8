// The cold-start estimates (start.hpp) and their bindings.
#include "start.hpp"

#include <cmath>
#include <limits>

#include "arrays.hpp"
#include "pymath.hpp"
#include "stages.hpp"
#include "window.hpp"

namespace tactiled {

double line_sum(long long n, double pitch, double x0, double depth, double nu) {
    const double d2 = depth * depth;
    const double c = 2.0 * depth / M_PI;
    double total = 0.0;
    for (long long m = 0; m < n; ++m) {
        const double u = static_cast<double>(m) * pitch - x0;
        const double u2 = u * u;
        const double s = u2 + d2;
        total += c * (d2 - nu * u2) / (s * s);
    }
    return total;
}

double force_from_total(double total, double modulus, long long rows, double dx, double depth_x,
                        double nu_x, long long cols, double dy, double depth_y, double nu_y,
                        double x0, double y0) {
    const double sx = line_sum(rows, dx, x0, depth_x, nu_x);
    const double sy = line_sum(cols, dy, y0, depth_y, nu_y);
    const double est = total * modulus / py_max(sx * sy, 1e-12);
    return py_min(py_max(est, 1e-3), 50.0);
}

void features(const double* s, long long rows, long long cols, long long m, long long n,
              double force, double out[9]) {
    const double c = s[m * cols + n];
    for (int i = 0; i < 9; ++i) out[i] = std::numeric_limits<double>::quiet_NaN();
    int k = 0;
    for (int i = -1; i <= 1; ++i)
        for (int j = -1; j <= 1; ++j) {
            if (i == 0 && j == 0) continue;
            if (0 <= m + i && m + i < rows && 0 <= n + j && n + j < cols)
                out[k] = s[(m + i) * cols + n + j] / c;
            ++k;
        }
    out[8] = 1.0 * std::log(py_max(c, 1e-12) / force);  // the peak's weight is 1
}

void nearest(const double* table, long long n, long long m, const double* feat, long long k,
             std::vector<double>& dist, std::vector<long long>& index) {
    std::vector<double> q(m);
    for (long long j = 0; j < m; ++j) {
        const double v = feat[j];
        q[j] = v != v ? 0.0 : py_min(py_max(v, -1e6), 1e6);
    }
    k = k < n ? k : n;
    dist.assign(k, std::numeric_limits<double>::infinity());
    index.assign(k, -1);
    if (k <= 0) return;
    for (long long i = 0; i < n; ++i) {
        const double* row = table + i * m;
        const double worst = dist[k - 1];
        double a0 = 0.0, a1 = 0.0, a2 = 0.0, a3 = 0.0;
        long long j = 0;
        while (j + 4 <= m) {
            const double t0 = row[j] - q[j], t1 = row[j + 1] - q[j + 1];
            const double t2 = row[j + 2] - q[j + 2], t3 = row[j + 3] - q[j + 3];
            a0 += t0 * t0;
            a1 += t1 * t1;
            a2 += t2 * t2;
            a3 += t3 * t3;
            j += 4;
            if (a0 + a1 + a2 + a3 >= worst) break;
        }
        double d = a0 + a1 + a2 + a3;
        if (d >= worst) continue;
        while (j < m) {
            const double t = row[j] - q[j];
            d += t * t;
            ++j;
        }
        if (d < worst) {  // insert, keeping the buffer sorted (an equal one stays ahead)
            long long pos = k - 1;
            while (pos > 0 && dist[pos - 1] > d) {
                dist[pos] = dist[pos - 1];
                index[pos] = index[pos - 1];
                --pos;
            }
            dist[pos] = d;
            index[pos] = i;
        }
    }
    for (auto& d : dist) d = std::sqrt(d);
}

std::vector<long long> pick_separated(const double* angles, long long n, long long count,
                                      double min_separation) {
    std::vector<long long> chosen{0};
    std::vector<double> sep(n, 180.0);
    while (static_cast<long long>(chosen.size()) < count) {
        const double last = angles[chosen.back()];
        long long nxt = -1;
        for (long long i = 0; i < n; ++i) {
            const double d = std::fabs(py_mod(angles[i] - last + 90.0, 180.0) - 90.0);
            if (d < sep[i]) sep[i] = d;
            if (nxt < 0 && sep[i] >= min_separation) nxt = i;
        }
        if (nxt < 0) break;
        chosen.push_back(nxt);
    }
    return chosen;
}

namespace {
py::array_t<double> features_array(const Arr& strain, long long m, long long n, double force) {
    long long rows, cols;
    frame_shape(strain, rows, cols);
    if (m < 0 || m >= rows || n < 0 || n >= cols) throw py::index_error("peak outside the frame");
    double out[9];
    features(strain.data(), rows, cols, m, n, force, out);
    return to_array(std::vector<double>(out, out + 9));
}
}  // namespace

void bind_start(py::module_& m) {
    m.def("line_sum", &line_sum);
    m.def("force_from_total", &force_from_total);
    m.def("features", &features_array);
    m.def("start_point",
          [](Arr strain, long long mm, long long n, double total, double modulus, long long rows,
             double dx, double depth_x, double nu_x, long long cols, double dy, double depth_y,
             double nu_y) {
              long long fr, fc;
              frame_shape(strain, fr, fc);
              if (mm < 0 || mm >= fr || n < 0 || n >= fc) throw py::index_error("peak outside the frame");
              double x0, y0;
              peak_centre(strain.data(), fr, fc, mm, n, dx, dy, x0, y0);
              const double f0 = force_from_total(total, modulus, rows, dx, depth_x, nu_x, cols, dy,
                                                 depth_y, nu_y, x0, y0);
              return py::make_tuple(x0, y0, f0, features_array(strain, mm, n, f0));
          });
    m.def("nearest", [](Arr table, Arr feat, long long k) {
        const long long n = dim(table, 0), w = dim(table, 1);
        if (feat.size() != w) throw py::value_error("nearest: feat needs one entry per column of table");
        std::vector<double> d;
        std::vector<long long> idx;
        nearest(table.data(), n, w, feat.data(), k, d, idx);
        py::array_t<long long> out_i(static_cast<py::ssize_t>(idx.size()));
        for (size_t i = 0; i < idx.size(); ++i) out_i.mutable_data()[i] = idx[i];
        return py::make_tuple(to_array(d), out_i);
    });
    m.def("pick_separated", [](Arr angles, long long count, double min_separation) {
        if (angles.size() < 1) throw py::index_error("pick_separated: no angles");
        py::list out;
        for (long long i : pick_separated(angles.data(), angles.size(), count, min_separation)) out.append(i);
        return out;
    });
}
}  // namespace tactiled
