// Contact models: each model's free parameters mapped onto the physics' six inputs
// (kappa_a, kappa_b, psi, F, x0, y0); Python reference: tactiled/fit/models.py, physical_map.
//
// cylinder [ln R, psi, ln F, x0, y0]: kappa_a = 1/R, kappa_b = 0;
// sphere   [ln R, ln F, x0, y0]: kappa_a = kappa_b = 1/R, psi = 0;
// general  [ln R_a, beta, psi, ln F, x0, y0]: kappa_a = 1/R_a, kappa_b = beta^2 kappa_a.
#pragma once

namespace tactiled {

struct Physical {
    double kappa_a, kappa_b, psi, force, x0, y0;
};

// The map of model `kind` (0 cylinder, 1 sphere, 2 general) at p; d (6 x k, row-major, zeroed
// by the caller) receives its Jacobian.
Physical physical_map(int kind, const double* p, double* d, int k);
}  // namespace tactiled
