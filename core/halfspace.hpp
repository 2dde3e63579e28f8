// The elastic half-space's Green's functions summed over point forces. Python reference:
// tactiled/physics/halfspace.py (green_weighted, the same algebra as green).
#pragma once
#include <cstdint>

namespace tactiled {

// out[k, i, j, p] = sum_n green(px[p] - ox[n], py[p] - oy[n])[i, j] * weights[k, j, n]
// (out: nk x 3 x 3 x npts, zeroed here; weights: nk x 3 x nn); mm, N, N/mm^2.
void green_weighted(const double* px, const double* py, std::int64_t npts, const double* ox,
                    const double* oy, std::int64_t nn, const double* weights, std::int64_t nk,
                    double z, double g, double nu, double* out);
}  // namespace tactiled
