// The rubber's plane-stress line-load response (MODEL.md, paper eqs. 1-4); Python reference:
// tactiled/physics/impulse.py.
#pragma once

namespace tactiled {
// h(u) = 2 d (d^2 - nu u^2) / (pi (u^2 + d^2)^2), in 1/mm; u and depth in mm.
inline double line_response(double u, double depth, double nu) {
    const double u2 = u * u;
    const double d2 = depth * depth;
    const double s = u2 + d2;
    return (2.0 * depth / 3.14159265358979323846) * (d2 - nu * u2) / (s * s);
}
}  // namespace tactiled
