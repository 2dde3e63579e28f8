// The scalar eccentricity solve (eccentricity.hpp) and its bindings.
#include "eccentricity.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>

#include "arrays.hpp"
#include "stages.hpp"

namespace tactiled {

EccentricityTables& eccentricity_tables() {
    static EccentricityTables tables;
    return tables;
}

void ellip_ke(double m, double m1, double& k, double& e) {
    double a = 1.0;
    double b = std::sqrt(m1);
    double s = 0.5 * m;  // 2^-1 c_0^2 with c_0^2 = m
    double p = 0.5;
    for (int i = 0; i < 60; ++i) {
        const double c = 0.5 * (a - b);
        const double a_next = 0.5 * (a + b);
        b = std::sqrt(a * b);
        a = a_next;
        p *= 2.0;
        s += p * c * c;
        if (std::fabs(c) <= 1e-17 * a) break;
    }
    k = M_PI / (2.0 * a);
    e = k * (1.0 - s);
}

double horner(const std::vector<double>& coef_high_first, double m) {
    double acc = 0.0;
    for (double c : coef_high_first) acc = acc * m + c;
    return acc;
}

void kernel_scalar(double m, double m1, double& dm, double& pm, double& ddm, double& dpm) {
    const EccentricityTables& t = eccentricity_tables();
    if (m < t.series_below) {
        dm = horner(t.dm_h, m);
        pm = horner(t.pm_h, m);
        ddm = horner(t.ddm_h, m);
        dpm = horner(t.dpm_h, m);
        return;
    }
    double k, e;
    ellip_ke(m, m1, k, e);
    const double dk = (e - m1 * k) / (2.0 * m * m1);
    const double de = (e - k) / (2.0 * m);
    const double d = k - e;
    const double nd = e * (2.0 - m) / m1 - 2.0 * k;  // N - D = E/m1 - K - (K - E)
    const double dnd = de * (2.0 - m) / m1 + e / (m1 * m1) - 2.0 * dk;
    dm = d / m;
    pm = nd / m;
    ddm = ((dk - de) * m - d) / (m * m);
    dpm = (dnd * m - nd) / (m * m);
}

LogSolution solve_log_scalar(double x, int newton_steps) {
    const EccentricityTables& t = eccentricity_tables();
    if (t.xt.size() < 2) throw std::runtime_error("eccentricity tables not set");
    x = std::min(std::max(x, t.x_min), t.x_max);
    // np.searchsorted(xt, x, side="right") - 1
    const auto n = static_cast<long long>(t.xt.size());
    long long i = static_cast<long long>(std::upper_bound(t.xt.begin(), t.xt.end(), x) - t.xt.begin()) - 1;
    i = std::min(std::max(i, 0LL), n - 2);
    const double x0 = t.xt[i], x1 = t.xt[i + 1];
    double y = t.yt0 + t.dy * (static_cast<double>(i) + (x - x0) / (x1 - x0));
    double m = 0, m1 = 0, dm = 0, pm = 0, ddm = 0, dpm = 0, dxdy = 0;
    for (int step = 0; step < newton_steps + 1; ++step) {
        m = 1.0 / (1.0 + std::exp(-y));
        m1 = 1.0 / (1.0 + std::exp(y));
        kernel_scalar(m, m1, dm, pm, ddm, dpm);
        dxdy = (dpm / pm - ddm / dm) * m * m1;
        if (step == newton_steps) break;
        y -= (std::log(pm / dm) - x) / dxdy;
    }
    const double dm_dx = m * m1 / dxdy;
    return {m, m1, std::log(dm), ddm / dm * dm_dx, -dm_dx / m1};
}

namespace {
std::vector<double> vec(const Arr& a) { return std::vector<double>(a.data(), a.data() + a.size()); }
}  // namespace

void bind_eccentricity(py::module_& m) {
    m.def("set_eccentricity_tables",
          [](Arr xt, double yt0, double dy, double x_min, double x_max, double series_below, Arr dm_h,
             Arr pm_h, Arr ddm_h, Arr dpm_h) {
              EccentricityTables& t = eccentricity_tables();
              t.xt = vec(xt);
              t.yt0 = yt0;
              t.dy = dy;
              t.x_min = x_min;
              t.x_max = x_max;
              t.series_below = series_below;
              t.dm_h = vec(dm_h);
              t.pm_h = vec(pm_h);
              t.ddm_h = vec(ddm_h);
              t.dpm_h = vec(dpm_h);
          },
          "Hand the Python module's table and series coefficients to the core (once, at import).");
    m.def("ellip_ke", [](double mm, double m1) {
        double k, e;
        ellip_ke(mm, m1, k, e);
        return py::make_tuple(k, e);
    });
    m.def("kernel_scalar", [](double mm, double m1) {
        double dm, pm, ddm, dpm;
        kernel_scalar(mm, m1, dm, pm, ddm, dpm);
        return py::make_tuple(dm, pm, ddm, dpm);
    });
    m.def("solve_log_scalar", [](double x, int newton_steps) {
        const LogSolution s = solve_log_scalar(x, newton_steps);
        return py::make_tuple(s.m, s.m1, s.log_f, s.dlogf_dx, s.dlogm1_dx);
    }, py::arg("x"), py::arg("newton_steps") = 1);
}
}  // namespace tactiled
