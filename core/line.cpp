// The line contact (line.hpp) and its bindings.  Every complex expression is written in the
// Python reference's order of operations (pycomplex.hpp gives CPython's arithmetic).
#include "line.hpp"

#include <cmath>

#include "arrays.hpp"
#include "stages.hpp"

namespace tactiled {
namespace {

// G(u) = A/(D - i sig u)^2 + B/(D - i sig u)
Cx g_of(double a, double b, double d, double sig, Cx u) {
    const Cx w = d - (J1 * sig) * u;
    return a / (w * w) + b / w;
}

// dG/du
Cx dg_of(double a, double b, double d, double sig, Cx u) {
    const Cx w = d - (J1 * sig) * u;
    return (J1 * sig) * ((2.0 * a) / ((w * w) * w) + b / (w * w));
}

// integral over real t of G1(p1 + q1 t) G2(p2 + q2 t): one residue, or a principal value when
// a factor does not vary along the line (q = 0).
Cx pair(double a1, double b1, double d1, double s1, double p1, double q1, double a2, double b2,
        double d2, double s2, double p2, double q2) {
    if (std::fabs(q1) < AXIS_EPS) return ((g_of(a1, b1, d1, s1, cx(p1) + Cx{0.0, 0.0}) * M_PI) * b2) / std::fabs(q2);
    if (std::fabs(q2) < AXIS_EPS) return ((g_of(a2, b2, d2, s2, cx(p2) + Cx{0.0, 0.0}) * M_PI) * b1) / std::fabs(q1);
    const double im1 = -s1 * d1 / q1;  // imaginary parts of the poles in t
    const double im2 = -s2 * d2 / q2;
    if ((im1 > 0.0) == (im2 > 0.0)) return {0.0, 0.0};  // both poles on one side
    Cx res;
    if (im1 > 0.0) {
        const Cx t = (((-J1) * s1) * d1 - p1) / q1;
        const Cx u2 = p2 + q2 * t;
        res = ((a1 / ((-q1) * q1)) * q2) * dg_of(a2, b2, d2, s2, u2) +
              (b1 / (((-J1) * s1) * q1)) * g_of(a2, b2, d2, s2, u2);
    } else {
        const Cx t = (((-J1) * s2) * d2 - p2) / q2;
        const Cx u1 = p1 + q1 * t;
        res = ((a2 / ((-q2) * q2)) * q1) * dg_of(a1, b1, d1, s1, u1) +
              (b2 / (((-J1) * s2) * q2)) * g_of(a1, b1, d1, s1, u1);
    }
    return (Cx{0.0, 2.0} * M_PI) * res;
}

}  // namespace

double along_line(double px, double py, double c, double s, const double* imp) {
    const double dx = imp[0], nux = imp[1], dy = imp[2], nuy = imp[3];
    const double ax = (1.0 + nux) * dx, bx = 1.0 - nux;
    const double ay = (1.0 + nuy) * dy, by = 1.0 - nuy;
    const Cx both = pair(ax, bx, dx, 1.0, px, -c, ay, by, dy, 1.0, py, -s) +
                    pair(ax, bx, dx, 1.0, px, -c, ay, by, dy, -1.0, py, -s);
    return both.re / ((2.0 * M_PI) * M_PI);
}

LineCoef line_coefficients(double c, double s, const double* imp) {
    const double dx = imp[0], nux = imp[1], dy = imp[2], nuy = imp[3];
    const double ax = (1.0 + nux) * dx, bx = 1.0 - nux;
    const double ay = (1.0 + nuy) * dy, by = 1.0 - nuy;
    const double ac = std::fabs(c), as = std::fabs(s);
    const double dac = c >= 0.0 ? -s : s;  // d|cos|/d psi
    const double das = s >= 0.0 ? c : -c;  // d|sin|/d psi
    LineCoef k;
    k.v = dy * ac + dx * as;
    k.dv = dy * dac + dx * das;
    k.a = 2.0 * ax * ay * (ac * as);
    k.da = 2.0 * ax * ay * (dac * as + ac * das);
    k.b = ax * by * as + ay * bx * ac;
    k.db = ax * by * das + ay * bx * dac;
    k.cc = bx * by;
    return k;
}

namespace {
// z = 1/(v + i dist) and the parts of z^2, z^3 (line.py's _powers)
struct ZPowers {
    double zr, zi, r2, i2, r3;
};

ZPowers z_powers(double v, double dist) {
    const double inv = 1.0 / (v * v + dist * dist);
    const double zr = v * inv;
    const double zi = -dist * inv;
    const double r2 = zr * zr - zi * zi;
    const double i2 = 2.0 * zr * zi;
    return {zr, zi, r2, i2, r2 * zr - i2 * zi};
}
}  // namespace

double across_value(double dist, const LineCoef& k) {
    const ZPowers z = z_powers(k.v, dist);
    return (k.a * z.r3 + k.b * z.r2 + k.cc * z.zr) / M_PI;
}

std::vector<double> line_strain_points(double load, double half_width, double psi, double cx_,
                                       double cy_, const double* px, const double* py, int n,
                                       const double* imp, double modulus, const double* nodes,
                                       const double* weights, int nn) {
    const double c = std::cos(psi), s = std::sin(psi);
    std::vector<double> out(n, 0.0);
    const double scale = 2.0 * load / (M_PI * modulus);
    const LineCoef k = line_coefficients(c, s, imp);
    for (int j = 0; j < n; ++j) {
        double acc = 0.0;
        for (int i = 0; i < nn; ++i) {
            const double off = half_width * nodes[i];  // across the line, along n = (-s, c)
            const double qx = px[j] - cx_ + off * s, qy = py[j] - cy_ - off * c;
            acc += weights[i] * across_value(-qx * s + qy * c, k);
        }
        out[j] = scale * acc;
    }
    return out;
}

LineAngle line_angle(double psi, const double* imp) {
    const double c = std::cos(psi), s = std::sin(psi);
    const bool near = std::fabs(c) < AXIS_NEAR || std::fabs(s) < AXIS_NEAR;
    const LineCoef at = line_coefficients(c, s, imp);
    return {c, s, near, at,
            near ? line_coefficients(std::cos(psi + AXIS_NUDGE), std::sin(psi + AXIS_NUDGE), imp) : at};
}

void across_at(double dist, const LineAngle& ang, const double* imp, double& val, double& d_dist,
               double& d_psi) {
    (void)imp;
    const LineCoef& k = ang.kj;
    const ZPowers z = z_powers(k.v, dist);
    const double zr = z.zr, zi = z.zi, r2 = z.r2, i2 = z.i2, r3 = z.r3;
    const double i3 = r2 * zi + i2 * zr;
    const double r4 = r2 * r2 - i2 * i2;
    const double i4 = 2.0 * r2 * i2;
    val = ang.near ? across_value(dist, ang.k0) : (k.a * r3 + k.b * r2 + k.cc * zr) / M_PI;
    d_dist = (3.0 * k.a * i4 + 2.0 * k.b * i3 + k.cc * i2) / M_PI;
    d_psi = (k.da * r3 + k.db * r2 - k.dv * (3.0 * k.a * r4 + 2.0 * k.b * r3 + k.cc * r2)) / M_PI;
}

void across_line(double dist, double psi, const double* imp, bool want, double& val,
                 double& d_dist, double& d_psi) {
    if (!want) {
        const double c = std::cos(psi), s = std::sin(psi);
        val = along_line((-dist) * s, dist * c, c, s, imp);
        d_dist = 0.0;
        d_psi = 0.0;
        return;
    }
    across_at(dist, line_angle(psi, imp), imp, val, d_dist, d_psi);
}

void line_residual(const double* p, const double* px, const double* py, int n, double ref_x,
                   double ref_y, const double* imp, double modulus, double compliance,
                   const double* nodes, const double* weights, int nn, const double* target,
                   const bool* valid, const double* inv_scale, std::vector<double>& r,
                   std::vector<double>& jac) {
    const double r_ = std::exp(p[0]), psi = p[1], load = std::exp(p[2]), off = p[3];
    const double b = std::sqrt(4.0 * load * r_ * compliance / M_PI);
    const double c = std::cos(psi), s = std::sin(psi);
    const LineAngle ang = line_angle(psi, imp);
    const double scale = 2.0 * load / (M_PI * modulus);
    r.assign(n, 0.0);
    jac.assign(static_cast<size_t>(n) * 4, 0.0);
    for (int k = 0; k < n; ++k) {
        if (!valid[k]) continue;
        const double ex = px[k] - ref_x, ey = py[k] - ref_y;
        const double e = (-ex) * s + ey * c;
        const double de = (-ex) * c - ey * s;  // d e / d psi
        double v = 0.0, dd = 0.0, du = 0.0, dpsi = 0.0;
        for (int i = 0; i < nn; ++i) {
            double val, l_d, l_psi;
            across_at(e - off - b * nodes[i], ang, imp, val, l_d, l_psi);
            const double wi = weights[i];
            v += wi * val;
            dd += wi * l_d;
            du += wi * l_d * nodes[i];
            dpsi += wi * (l_d * de + l_psi);
        }
        const double w = inv_scale[k];
        r[k] = (scale * v - target[k]) * w;
        jac[k * 4 + 0] = (-scale) * 0.5 * b * du * w;
        jac[k * 4 + 1] = scale * dpsi * w;
        jac[k * 4 + 2] = (scale * v - scale * 0.5 * b * du) * w;
        jac[k * 4 + 3] = (-scale) * dd * w;
    }
}

void line_points(const double* xs, int nr, const double* ys, int nc, const double* ex,
                 const double* ey, std::vector<double>& px, std::vector<double>& py,
                 double& ref_x, double& ref_y) {
    px.assign(static_cast<size_t>(nr) * nc, 0.0);
    py.assign(px.size(), 0.0);
    double sx = 0.0, sy = 0.0;
    for (int i = 0; i < nr; ++i)
        for (int j = 0; j < nc; ++j) {
            const int k = i * nc + j;
            px[k] = xs[i] + ex[k];
            py[k] = ys[j] + ey[k];
            sx += px[k];
            sy += py[k];
        }
    ref_x = sx / static_cast<double>(nr * nc);
    ref_y = sy / static_cast<double>(nr * nc);
}

namespace {
int len(const Arr& a) { return static_cast<int>(a.size()); }
}

void bind_line(py::module_& m) {
    m.def("along_line", [](double px, double py_, double c, double s, Arr imp) {
        return along_line(px, py_, c, s, imp.data());
    });
    m.def("line_strain_points",
          [](double load, double hw, double psi, double cx_, double cy_, Arr px, Arr py_, Arr imp,
             double modulus, Arr nodes, Arr weights) {
              if (py_.size() != px.size() || weights.size() != nodes.size())
                  throw py::value_error("line_strain_points: px/py and nodes/weights must match");
              return to_array(line_strain_points(load, hw, psi, cx_, cy_, px.data(), py_.data(),
                                                 len(px), imp.data(), modulus, nodes.data(),
                                                 weights.data(), len(nodes)));
          });
    m.def("across_line", [](double dist, double psi, Arr imp, bool want) {
        double v, dd, dp;
        across_line(dist, psi, imp.data(), want, v, dd, dp);
        return py::make_tuple(v, dd, dp);
    });
    m.def("line_residual",
          [](Arr p, Arr px, Arr py_, double ref_x, double ref_y, Arr imp, double modulus,
             double compliance, Arr nodes, Arr weights, Arr target, BArr valid, Arr inv_scale) {
              const int n = len(px);
              if (py_.size() != n || target.size() != n || valid.size() != n || inv_scale.size() != n ||
                  weights.size() != nodes.size() || p.size() < 4)
                  throw py::value_error("line_residual: one entry per point in px, py, target, valid, inv_scale");
              std::vector<double> r, jac;
              line_residual(p.data(), px.data(), py_.data(), n, ref_x, ref_y, imp.data(), modulus,
                            compliance, nodes.data(), weights.data(), len(nodes), target.data(),
                            valid.data(), inv_scale.data(), r, jac);
              return py::make_tuple(to_array(r), to_array(jac, n, 4));
          });
    m.def("line_points", [](Arr xs, Arr ys, Arr ex, Arr ey) {
        if (ex.size() != xs.size() * ys.size() || ey.size() != ex.size())
            throw py::value_error("line_points: ex, ey need one entry per tactel of xs x ys");
        std::vector<double> px, py_;
        double rx, ry;
        line_points(xs.data(), len(xs), ys.data(), len(ys), ex.data(), ey.data(), px, py_, rx, ry);
        return py::make_tuple(to_array(px), to_array(py_), rx, ry);
    });
}
}  // namespace tactiled
