// The line model's band: a flood fill from the peak. Python reference: tactiled/fit/linewindow.py
// (ridge_band).
#pragma once
#include <cstdint>

namespace tactiled {

// The usable (`ok`) tactels above `threshold` 8-connected to (m, n) of a rows x cols frame
// (row-major), grown by one tactel on every side, usable ones only, written to `out`.
void ridge_band(const double* clean, const bool* ok, std::int64_t rows, std::int64_t cols,
                std::int64_t m, std::int64_t n, double threshold, bool* out);
}  // namespace tactiled
