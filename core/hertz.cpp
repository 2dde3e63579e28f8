// The Hertz ellipse (hertz.hpp) and its binding.
#include "hertz.hpp"

#include <cmath>

#include "arrays.hpp"
#include "eccentricity.hpp"
#include "pymath.hpp"
#include "stages.hpp"

namespace tactiled {

EllipseCore ellipse_core(double kappa_a, double kappa_b, double psi, double force,
                         double finger_radius, double compliance, double* jac) {
    const double s2 = std::sin(2.0 * psi), c2 = std::cos(2.0 * psi);
    const double kf = 1.0 / finger_radius;
    // M = [[p, q], [q, s]]; with cos^2 = (1 + c2)/2, sin^2 = (1 - c2)/2.
    const double ksum = kappa_a + kappa_b, kdif = kappa_b - kappa_a;
    const double p = 0.25 * (ksum + kdif * c2);
    const double s = 0.25 * (ksum - kdif * c2 + 2.0 * kf);
    const double q = 0.25 * kdif * s2;
    const double mu = 0.5 * (p + s);
    const double half = 0.5 * (p - s);
    const double delta = std::hypot(half, q);
    // C' = det(M) / A', not mu - delta: near a line contact mu - delta cancels to nothing.
    // det(2M) = ka kb + kf (kb cos^2 + ka sin^2).
    const double sp = std::sin(psi), cp = std::cos(psi);
    const double sin2 = sp * sp, cos2 = cp * cp;
    const double det = 0.25 * (kappa_a * kappa_b + kf * (kappa_b * cos2 + kappa_a * sin2));
    const double c_prime = det / (mu + delta);  // C'
    if (!(c_prime > 0.0)) return {-1.0, -1.0, 0.0, 1.0};
    const double phi = 0.5 * std::atan2(q, half);  // direction of the A' eigenvector
    const double theta = py_mod(phi + 0.5 * M_PI, M_PI);
    LogSolution e;
    if (delta > 0.0) {
        const double x = std::log(2.0 * delta / c_prime);  // log(lambda - 1), no cancellation
        e = solve_log_scalar(x, 1);
    } else {  // circular contact: sphere-like limit m = 0, f = pi/4
        e = {0.0, 1.0, std::log(M_PI / 4.0), 0.0, 0.0};
    }
    const double log_a = (std::log(3.0 * compliance / (2.0 * M_PI)) + std::log(force) + e.log_f
                          - std::log(c_prime)) / 3.0;
    const double a = std::exp(log_a);
    const double b = a * std::sqrt(e.m1);
    if (jac != nullptr) {
        // d(p, s, q) / d(kappa_a, kappa_b, psi)
        for (int i = 0; i < 3; ++i) {
            double dp, ds, dq;
            if (i == 0) {
                dp = 0.25 * (1.0 - c2); ds = 0.25 * (1.0 + c2); dq = -0.25 * s2;
            } else if (i == 1) {
                dp = 0.25 * (1.0 + c2); ds = 0.25 * (1.0 - c2); dq = 0.25 * s2;
            } else {
                dp = -0.5 * kdif * s2; ds = 0.5 * kdif * s2; dq = 0.5 * kdif * c2;
            }
            const double dmu = 0.5 * (dp + ds);
            const double dhalf = 0.5 * (dp - ds);
            double dc, dx;
            if (delta > 0.0) {
                const double ddelta = (half * dhalf + q * dq) / delta;
                jac[2 * 4 + i] = 0.5 * (half * dq - q * dhalf) / (delta * delta);
                dc = dmu - ddelta;
                dx = ddelta / delta - dc / c_prime;
            } else {
                jac[2 * 4 + i] = 0.0;
                dc = dmu;
                dx = 0.0;
            }
            const double dlog_a = (e.dlogf_dx * dx - dc / c_prime) / 3.0;
            jac[0 * 4 + i] = a * dlog_a;
            jac[1 * 4 + i] = b * (dlog_a + 0.5 * e.dlogm1_dx * dx);
        }
        jac[0 * 4 + 3] = a / (3.0 * force);
        jac[1 * 4 + 3] = b / (3.0 * force);
        jac[2 * 4 + 3] = 0.0;
    }
    return {a, b, theta, e.m};
}

void bind_hertz(py::module_& m) {
    m.def("ellipse_core",
          [](double ka, double kb, double psi, double force, double rf, double comp,
             py::array_t<double, py::array::c_style> jac) {
              const bool want = jac.ndim() == 2 && jac.shape(0) == 3 && jac.shape(1) == 4;
              const EllipseCore e = ellipse_core(ka, kb, psi, force, rf, comp,
                                                 want ? jac.mutable_data() : nullptr);
              return py::make_tuple(e.a, e.b, e.theta, e.m);
          },
          "tactiled.physics.hertz.ellipse_core: (a, b, theta, m), filling jac when it is 3x4.");
}
}  // namespace tactiled
