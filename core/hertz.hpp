// Hertz contact ellipse of a rigid paraboloid on the cylindrical finger (MODEL.md, paper eqs.
// 5-12); Python reference: tactiled/physics/hertz.py, ellipse_core.
//
// M = 1/2 ( Rot(psi) diag(kappa_b, kappa_a) Rot(psi)^T + diag(0, 1/R_f) ) has eigenvalues
// A' >= C'; the major semi-axis a lies along C''s eigenvector (direction theta),
// b = a sqrt(1 - m), and a^3 = 3 F k (K(m) - E(m)) / (2 pi m C').
#pragma once

namespace tactiled {

struct EllipseCore {
    double a, b, theta, m;  // mm, mm, rad in [0, pi), m = 1 - (b/a)^2; a = -1: an infinite line
};

// (a, b, theta, m) for curvatures in 1/mm, psi in rad, force in N, finger radius in mm and
// compliance k = (1 - nu_f^2)/E in mm^2/N; with jac (3x4, row-major) not null, fills it with
// d(a, b, theta)/d(kappa_a, kappa_b, psi, F).
EllipseCore ellipse_core(double kappa_a, double kappa_b, double psi, double force,
                         double finger_radius, double compliance, double* jac);
}  // namespace tactiled
