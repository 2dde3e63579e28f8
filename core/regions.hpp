// Separate pressed regions of a frame by topographic prominence. Python reference:
// tactiled/fit/regions.py (watershed).
#pragma once
#include <cstdint>
#include <vector>

namespace tactiled {

// One region of `watershed`: its peak tactel (row-major index) and strain, the saddle that
// joins it to a higher region (NaN for none), and the lower maxima it absorbed (tactel, strain).
struct WaterRegion {
    std::int64_t peak_idx;
    double peak;
    double saddle;
    std::vector<std::pair<std::int64_t, double>> absorbed;
    std::vector<std::int64_t> members;
};

// The regions of `flat` (rows x cols, row-major, unusable tactels -inf) whose peaks stand
// above significant_z sigmas, highest first (ties: as the reference ranks them), each
// tactel's region in `labels` (-1 for none).
std::vector<WaterRegion> watershed(const double* flat, std::int64_t rows, std::int64_t cols,
                                   double sigma, double support_z, double significant_z,
                                   double separation_z, double separation_share,
                                   double absorbed_share, std::vector<std::int64_t>& labels);
}  // namespace tactiled
