// The forward model's inner loop: quadrature of the rubber's impulse response over the
// contact's nodes (MODEL.md); Python reference: tactiled/physics/kernels.py.
//
// A contact ellipse (centre x0, y0, semi-axes a, b, direction theta) carries the unit-disk rule
// (u, v, w) onto nodes x_q = x0 + a u c - b v s, y_q = y0 + a u s + b v c; a tactel at (X, Y)
// reads scale F sum_q w_q h_x(X - x_q) h_y(Y - y_q), with the separable response
// h(t) = 2 d (d^2 - nu t^2) / (pi (t^2 + d^2)^2).
#pragma once
#include <vector>

// The hottest loops get an AVX2 copy beside the baseline one, chosen when the module loads
// (GCC's function multi-versioning).  AVX2 without FMA: the same operations, the same numbers.
#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && defined(__linux__)
#define TACTILED_HOT __attribute__((target_clones("avx2", "default")))
#else
#define TACTILED_HOT
#endif

namespace tactiled {

// Strains (mx x ny) and their Jacobian (mx x ny x 6) in (kappa_a, kappa_b, psi, F, x0, y0).
// geo = [x0, y0, a, b, theta, F, scale] (mm, rad, N; scale = 3/(2 pi E)); hj the 3x4 Hertz
// Jacobian d(a, b, theta)/d(kappa_a, kappa_b, psi, F); imp = [d_x, nu_x, d_y, nu_y].
void strain_with_jacobian(const double* geo, const double* hj, const double* u, const double* v,
                          const double* w, int nq, const double* xs, int mx, const double* ys,
                          int ny, const double* imp, std::vector<double>& val,
                          std::vector<double>& jac);

// S[m, n] alone, the strain per unit force and scale.
std::vector<double> quadrature(double x0, double y0, double a, double b, double theta,
                               const double* u, const double* v, const double* w, int nq,
                               const double* xs, int mx, const double* ys, int ny, double dep_x,
                               double nu_x, double dep_y, double nu_y);

// The same sum at arbitrary points (px[k], py[k]) in mm.
std::vector<double> quadrature_points(double x0, double y0, double a, double b, double theta,
                                      const double* u, const double* v, const double* w, int nq,
                                      const double* px, const double* py, int npt,
                                      const double* imp);

// Scaled residuals (model - target) * inv_scale over a window's valid tactels (flattened
// row-major) and their Jacobian (rows x k) in a model's own parameters (dphys: 6 x k).  A
// displaced tactel (ex, ey) is taken to first order: s(X + e) = s(X) - e . ds/d(x0, y0).
void window_residual(const double* geo, const double* hj, const double* dphys, int k,
                     const double* u, const double* v, const double* w, int nq, const double* xs,
                     int mx, const double* ys, int ny, const double* imp, const double* target,
                     const bool* valid, const double* inv_scale, const double* ex,
                     const double* ey, std::vector<double>& r, std::vector<double>& jac);
}  // namespace tactiled
