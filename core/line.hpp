// Line contact on a flat array: a cylinder pressed on a flat cover (MODEL.md, "Other arrays");
// Python reference: tactiled/physics/line.py.
//
// Across the line the pressure is the 2-D Hertz line contact's, p(s) = 2P/(pi b) sqrt(1 - s^2/b^2),
// b = sqrt(4 P R k / pi).  Along the (infinite) line the integral of h_x h_y is exact: with
// h(u) = Re g(u)/pi, g(u) = (1 + nu) d/(d - i u)^2 + (1 - nu)/(d - i u) (one double pole),
// h_x h_y = Re[g_x g_y + g_x conj(g_y)] / (2 pi^2) and each product's integral over the real
// line is one residue.  Across the line a Gauss-Chebyshev (second kind) rule integrates the
// square-root pressure.
#pragma once
#include <vector>

#include "pycomplex.hpp"

namespace tactiled {

// Below this |cos psi| or |sin psi| the line lies along an axis: the principal value is taken.
constexpr double AXIS_EPS = 1e-12;
// Within this of an axis the partials are taken AXIS_NUDGE rad off it (the response's kink).
constexpr double AXIS_NEAR = 1e-7;
constexpr double AXIS_NUDGE = 1e-6;

// The across-line closed form's coefficients at a line's direction (cos, sin) and their
// derivatives in its angle (line.py's _coefficients): the one residue of along_line that does
// not vanish is L(d) = (A Re z^3 + B Re z^2 + C Re z)/pi, z = 1/(V + i d).
struct LineCoef {
    double v, dv, a, da, b, db, cc;
};

// What across_line needs of the angle psi (line.py's _line_angle): the coefficients at psi
// (the value's) and at psi nudged off an axis (the partials').
struct LineAngle {
    double c, s;
    bool near;
    LineCoef k0, kj;
};

LineCoef line_coefficients(double c, double s, const double* imp);

// L(d) of line_coefficients k at signed distance dist (mm) from the line (1/mm).
double across_value(double dist, const LineCoef& k);

// integral over the whole line of h_x(px - t c) h_y(py - t s) dt (1/mm).
double along_line(double px, double py, double c, double s, const double* imp);

// Strains at points (px, py) of a line contact of load per length `load` (N/mm), half-width
// (mm) along psi (rad) through (cx, cy); nodes/weights: a Gauss-Chebyshev rule on [-1, 1].
// L(d) of across_value at each point and node.
std::vector<double> line_strain_points(double load, double half_width, double psi, double cx,
                                       double cy, const double* px, const double* py, int n,
                                       const double* imp, double modulus, const double* nodes,
                                       const double* weights, int nn);

LineAngle line_angle(double psi, const double* imp);

// L(d, psi) at signed distance dist from the line, with its partials in dist and psi:
// L = (A Re z^3 + B Re z^2 + C Re z)/pi, z = 1/(V + i d) (line.py's _across_at).
void across_at(double dist, const LineAngle& ang, const double* imp, double& val, double& d_dist,
               double& d_psi);

// across_line: the partials only when `want` (else 0).
void across_line(double dist, double psi, const double* imp, bool want, double& val,
                 double& d_dist, double& d_psi);

// Scaled residuals of the line model p = [ln R, psi, ln P, c] at the valid points and their
// exact Jacobian (n x 4; 0 rows where not valid).
void line_residual(const double* p, const double* px, const double* py, int n, double ref_x,
                   double ref_y, const double* imp, double modulus, double compliance,
                   const double* nodes, const double* weights, int nn, const double* target,
                   const bool* valid, const double* inv_scale, std::vector<double>& r,
                   std::vector<double>& jac);

// A window's tactel positions (flattened row-major) from its grid and displacements, and
// their mean (the line's reference point).
void line_points(const double* xs, int nr, const double* ys, int nc, const double* ex,
                 const double* ey, std::vector<double>& px, std::vector<double>& py,
                 double& ref_x, double& ref_y);
}  // namespace tactiled
