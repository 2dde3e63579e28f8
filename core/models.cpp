// The models' parameter maps (models.hpp) and their binding.
#include "models.hpp"

#include <cmath>

#include "arrays.hpp"
#include "stages.hpp"

namespace tactiled {

Physical physical_map(int kind, const double* p, double* d, int k) {
    auto D = [d, k](int i, int j) -> double& { return d[i * k + j]; };
    if (kind == 0) {  // cylinder: ln_r, psi, ln_f, x0, y0
        const double ka = std::exp(-p[0]), f = std::exp(p[2]);
        D(0, 0) = -ka;
        D(2, 1) = 1.0;
        D(3, 2) = f;
        D(4, 3) = 1.0;
        D(5, 4) = 1.0;
        return {ka, 0.0, p[1], f, p[3], p[4]};
    }
    if (kind == 1) {  // sphere: ln_r, ln_f, x0, y0
        const double kk = std::exp(-p[0]), f = std::exp(p[1]);
        D(0, 0) = -kk;
        D(1, 0) = -kk;
        D(3, 1) = f;
        D(4, 2) = 1.0;
        D(5, 3) = 1.0;
        return {kk, kk, 0.0, f, p[2], p[3]};
    }
    // general: ln_ra, beta, psi, ln_f, x0, y0
    const double ka = std::exp(-p[0]), beta = p[1], f = std::exp(p[3]);
    const double kb = beta * beta * ka;
    D(0, 0) = -ka;
    D(1, 0) = -kb;
    D(1, 1) = 2.0 * beta * ka;
    D(2, 2) = 1.0;
    D(3, 3) = f;
    D(4, 4) = 1.0;
    D(5, 5) = 1.0;
    return {ka, kb, p[2], f, p[4], p[5]};
}

void bind_models(py::module_& m) {
    m.def("physical_map",
          [](int kind, Arr p, py::array_t<double, py::array::c_style> d) {
              const int need = kind == 0 ? 5 : kind == 1 ? 4 : 6;
              if (d.ndim() != 2 || d.shape(0) != 6 || d.shape(1) < need || p.size() < need)
                  throw py::value_error("physical_map: p of the model's size and d of (6, k) needed");
              const Physical ph = physical_map(kind, p.data(), d.mutable_data(),
                                               static_cast<int>(d.shape(1)));
              return py::make_tuple(ph.kappa_a, ph.kappa_b, ph.psi, ph.force, ph.x0, ph.y0);
          },
          "tactiled.fit.models.physical_map: the six physics inputs, filling d with the Jacobian.");
}
}  // namespace tactiled
