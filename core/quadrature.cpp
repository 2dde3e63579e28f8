// The quadrature kernels (quadrature.hpp) and their bindings.
#include "quadrature.hpp"

#include <cmath>

#include "arrays.hpp"
#include "stages.hpp"

namespace tactiled {
namespace {
const double INV_PI = 1.0 / M_PI;

// The separable response's constants, h(t) = c (d^2 - nu t^2) / (t^2 + d^2)^2, c = 2 d / pi,
// on each axis.
struct Axes {
    double cx, cy, dx2, dy2, nu_x, nu_y;
    Axes(double dep_x, double nux, double dep_y, double nuy)
        : cx(2.0 * dep_x * INV_PI), cy(2.0 * dep_y * INV_PI), dx2(dep_x * dep_x),
          dy2(dep_y * dep_y), nu_x(nux), nu_y(nuy) {}
};

// Node q of the unit-disk rule carried onto the ellipse: (x0 + a u c - b v s, y0 + a u s + b v c).
inline void node(double x0, double y0, double a, double b, double c, double s, double u, double v,
                 double& xq, double& yq) {
    const double au = a * u;
    const double bv = b * v;
    xq = x0 + au * c - bv * s;
    yq = y0 + au * s + bv * c;
}
}  // namespace

TACTILED_HOT void strain_with_jacobian(const double* geo, const double* hj, const double* u, const double* v,
                          const double* w, int nq, const double* xs, int mx, const double* ys,
                          int ny, const double* imp, std::vector<double>& val,
                          std::vector<double>& jac) {
    const double x0 = geo[0], y0 = geo[1], a = geo[2], b = geo[3], theta = geo[4], force = geo[5],
                 scale = geo[6];
    const double dep_x = imp[0], nu_x = imp[1], dep_y = imp[2], nu_y = imp[3];
    const double c = std::cos(theta), s = std::sin(theta);
    const double cx = 2.0 * dep_x * INV_PI;
    const double cy = 2.0 * dep_y * INV_PI;
    const double dx2 = dep_x * dep_x;
    const double dy2 = dep_y * dep_y;
    // node offsets from the centre and their motion per unit (a, b): (u c, u s), (-v s, v c)
    std::vector<double> ex(nq), ey(nq), uc(nq), us(nq), vs(nq), vc(nq);
    for (int q = 0; q < nq; ++q) {
        const double au = a * u[q];
        const double bv = b * v[q];
        ex[q] = au * c - bv * s;
        ey[q] = au * s + bv * c;
        uc[q] = u[q] * c;
        us[q] = u[q] * s;
        vs[q] = -v[q] * s;
        vc[q] = v[q] * c;
    }
    // the separable kernel tabulated per axis and node, with its slope; the y axis's stored
    // node-major (hy[q * ny + j]) so the sums below run along j, contiguous
    std::vector<double> hx(static_cast<size_t>(mx) * nq), dhx(hx.size());
    std::vector<double> hy(static_cast<size_t>(ny) * nq), dhy(hy.size());
    for (int i = 0; i < mx; ++i) {
        for (int q = 0; q < nq; ++q) {
            const double t = xs[i] - x0 - ex[q];
            const double t2 = t * t;
            const double sx = t2 + dx2;
            const double inv = w[q] / (sx * sx);
            hx[i * nq + q] = cx * (dx2 - nu_x * t2) * inv;
            dhx[i * nq + q] = 2.0 * cx * t * (nu_x * t2 - (nu_x + 2.0) * dx2) * inv / sx;
        }
    }
    for (int j = 0; j < ny; ++j) {
        for (int q = 0; q < nq; ++q) {
            const double t = ys[j] - y0 - ey[q];
            const double t2 = t * t;
            const double sy = t2 + dy2;
            const double inv = 1.0 / (sy * sy);
            hy[q * ny + j] = cy * (dy2 - nu_y * t2) * inv;
            dhy[q * ny + j] = 2.0 * cy * t * (nu_y * t2 - (nu_y + 2.0) * dy2) * inv / sy;
        }
    }
    // Each tactel's value and derivatives are sums over the nodes, taken in node order for
    // every tactel (the reference's order, so the same numbers); the loop runs over the
    // tactels innermost, independent sums the compiler can vectorise without reassociating.
    const size_t cells = static_cast<size_t>(mx) * ny;
    std::vector<double> sv(cells, 0.0), d0(cells, 0.0), d1(cells, 0.0), d2(cells, 0.0),
        d3(cells, 0.0), d4(cells, 0.0);
    for (int q = 0; q < nq; ++q) {
        const double ucq = uc[q], usq = us[q], vsq = vs[q], vcq = vc[q], exq = ex[q], eyq = ey[q];
        const double* hyq = &hy[static_cast<size_t>(q) * ny];
        const double* dhyq = &dhy[static_cast<size_t>(q) * ny];
        for (int i = 0; i < mx; ++i) {
            const double hxi = hx[i * nq + q], dhxi = dhx[i * nq + q];
            double* svi = &sv[static_cast<size_t>(i) * ny];
            double* d0i = &d0[static_cast<size_t>(i) * ny];
            double* d1i = &d1[static_cast<size_t>(i) * ny];
            double* d2i = &d2[static_cast<size_t>(i) * ny];
            double* d3i = &d3[static_cast<size_t>(i) * ny];
            double* d4i = &d4[static_cast<size_t>(i) * ny];
            for (int j = 0; j < ny; ++j) {
                // the kernel's argument is X - x_q, hence the minus signs on node motion
                const double ax_ = dhxi * hyq[j];  // d/d(node x) is minus this
                const double by_ = hxi * dhyq[j];  // d/d(node y) is minus this
                svi[j] += hxi * hyq[j];
                d0i[j] -= ax_;
                d1i[j] -= by_;
                d2i[j] -= ax_ * ucq + by_ * usq;
                d3i[j] -= ax_ * vsq + by_ * vcq;
                d4i[j] += ax_ * eyq - by_ * exq;  // theta: node motion (-ey, ex)
            }
        }
    }
    const double kf = scale * force;
    val.assign(cells, 0.0);
    jac.assign(cells * 6, 0.0);
    for (size_t c = 0; c < cells; ++c) {
        double* jj = &jac[c * 6];
        for (int k = 0; k < 4; ++k)
            jj[k] = kf * (d2[c] * hj[0 * 4 + k] + d3[c] * hj[1 * 4 + k] + d4[c] * hj[2 * 4 + k]);
        jj[3] += scale * sv[c];
        jj[4] = kf * d0[c];
        jj[5] = kf * d1[c];
        val[c] = kf * sv[c];
    }
}

std::vector<double> quadrature(double x0, double y0, double a, double b, double theta,
                               const double* u, const double* v, const double* w, int nq,
                               const double* xs, int mx, const double* ys, int ny, double dep_x,
                               double nu_x, double dep_y, double nu_y) {
    std::vector<double> val(static_cast<size_t>(mx) * ny, 0.0);
    std::vector<double> hx(mx);
    const double c = std::cos(theta), s = std::sin(theta);
    const Axes ax(dep_x, nu_x, dep_y, nu_y);
    const double cx = ax.cx, cy = ax.cy, dx2 = ax.dx2, dy2 = ax.dy2;
    for (int q = 0; q < nq; ++q) {
        double xq, yq;
        node(x0, y0, a, b, c, s, u[q], v[q], xq, yq);
        for (int i = 0; i < mx; ++i) {
            const double t = xs[i] - xq;
            const double t2 = t * t;
            const double sx = t2 + dx2;
            hx[i] = cx * (dx2 - nu_x * t2) / (sx * sx) * w[q];
        }
        for (int j = 0; j < ny; ++j) {
            const double t = ys[j] - yq;
            const double t2 = t * t;
            const double sy = t2 + dy2;
            const double hyj = cy * (dy2 - nu_y * t2) / (sy * sy);
            for (int i = 0; i < mx; ++i) val[static_cast<size_t>(i) * ny + j] += hx[i] * hyj;
        }
    }
    return val;
}

std::vector<double> quadrature_points(double x0, double y0, double a, double b, double theta,
                                      const double* u, const double* v, const double* w, int nq,
                                      const double* px, const double* py, int npt,
                                      const double* imp) {
    const double dep_x = imp[0], nu_x = imp[1], dep_y = imp[2], nu_y = imp[3];
    std::vector<double> val(npt, 0.0);
    const double c = std::cos(theta), s = std::sin(theta);
    const Axes ax(dep_x, nu_x, dep_y, nu_y);
    const double cx = ax.cx, cy = ax.cy, dx2 = ax.dx2, dy2 = ax.dy2;
    for (int q = 0; q < nq; ++q) {
        double xq, yq;
        node(x0, y0, a, b, c, s, u[q], v[q], xq, yq);
        for (int k = 0; k < npt; ++k) {
            const double tx = px[k] - xq;
            const double tx2 = tx * tx;
            const double sx = tx2 + dx2;
            const double ty = py[k] - yq;
            const double ty2 = ty * ty;
            const double sy = ty2 + dy2;
            val[k] += cx * (dx2 - nu_x * tx2) / (sx * sx) * cy * (dy2 - nu_y * ty2) / (sy * sy) * w[q];
        }
    }
    return val;
}

void window_residual(const double* geo, const double* hj, const double* dphys, int k,
                     const double* u, const double* v, const double* w, int nq, const double* xs,
                     int mx, const double* ys, int ny, const double* imp, const double* target,
                     const bool* valid, const double* inv_scale, const double* ex,
                     const double* ey, std::vector<double>& r, std::vector<double>& jac) {
    std::vector<double> val, jac6;
    strain_with_jacobian(geo, hj, u, v, w, nq, xs, mx, ys, ny, imp, val, jac6);
    const int cells = mx * ny;
    int n = 0;
    for (int idx = 0; idx < cells; ++idx) n += valid[idx] ? 1 : 0;
    r.assign(n, 0.0);
    jac.assign(static_cast<size_t>(n) * k, 0.0);
    int row = 0;
    for (int idx = 0; idx < cells; ++idx) {
        if (!valid[idx]) continue;
        const double* j6 = &jac6[static_cast<size_t>(idx) * 6];  // (i, j) = (idx / ny, idx % ny)
        const double scale = inv_scale[idx];
        r[row] = (val[idx] - ex[idx] * j6[4] - ey[idx] * j6[5] - target[idx]) * scale;
        for (int c = 0; c < k; ++c) {
            double acc = 0.0;
            for (int e = 0; e < 6; ++e) acc += j6[e] * dphys[e * k + c];
            jac[static_cast<size_t>(row) * k + c] = acc * scale;
        }
        ++row;
    }
}

namespace {
int len(const Arr& a) { return static_cast<int>(a.size()); }

// The window arrays must hold one entry per grid tactel.
void check_window(py::ssize_t cells, const BArr& valid, const Arr& target, const Arr& inv_scale,
                  const Arr& ex, const Arr& ey) {
    if (valid.size() != cells || target.size() != cells || inv_scale.size() != cells ||
        ex.size() != cells || ey.size() != cells)
        throw py::value_error("window arrays must hold one entry per tactel of xs x ys");
}
}  // namespace

void bind_quadrature(py::module_& m) {
    m.def("strain_with_jacobian",
          [](Arr geo, Arr hj, Arr u, Arr v, Arr w, Arr xs, Arr ys, Arr imp) {
              std::vector<double> val, jac;
              strain_with_jacobian(geo.data(), hj.data(), u.data(), v.data(), w.data(), len(u),
                                   xs.data(), len(xs), ys.data(), len(ys), imp.data(), val, jac);
              return py::make_tuple(to_array(val, len(xs), len(ys)),
                                    to_array(jac, len(xs), len(ys), 6));
          });
    m.def("quadrature",
          [](double x0, double y0, double a, double b, double theta, Arr u, Arr v, Arr w, Arr xs,
             Arr ys, double dep_x, double nu_x, double dep_y, double nu_y) {
              return to_array(quadrature(x0, y0, a, b, theta, u.data(), v.data(), w.data(), len(u),
                                         xs.data(), len(xs), ys.data(), len(ys), dep_x, nu_x,
                                         dep_y, nu_y),
                              len(xs), len(ys));
          });
    m.def("quadrature_points",
          [](double x0, double y0, double a, double b, double theta, Arr u, Arr v, Arr w, Arr px,
             Arr py_, Arr imp) {
              return to_array(quadrature_points(x0, y0, a, b, theta, u.data(), v.data(), w.data(),
                                                len(u), px.data(), py_.data(), len(px), imp.data()));
          });
    m.def("window_residual",
          [](Arr geo, Arr hj, Arr dphys, Arr u, Arr v, Arr w, Arr xs, Arr ys, Arr imp, Arr target,
             BArr valid, Arr inv_scale, Arr ex, Arr ey) {
              check_window(xs.size() * ys.size(), valid, target, inv_scale, ex, ey);
              const int k = static_cast<int>(dim(dphys, 1));
              std::vector<double> r, jac;
              window_residual(geo.data(), hj.data(), dphys.data(), k, u.data(), v.data(), w.data(),
                              len(u), xs.data(), len(xs), ys.data(), len(ys), imp.data(),
                              target.data(), valid.data(), inv_scale.data(), ex.data(), ey.data(),
                              r, jac);
              return py::make_tuple(to_array(r), to_array(jac, static_cast<py::ssize_t>(r.size()), k));
          });
}
}  // namespace tactiled
