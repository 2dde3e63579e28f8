// The calibration kernels' array arguments as their bindings check them (core/calibrate.cpp):
// the table's segments and the matched filter's matrices, validated once per call so the
// per-tactel loops index them without checks.
#pragma once

#include <cstdint>

#include "arrays.hpp"
#include "calibrate.hpp"

namespace tactiled {
namespace calib {

// The segments of a table of n tactels (ValueError when they do not index each other).
Segments segments_of(const In<double>& offset, const In<double>& breaks,
                     const In<std::int64_t>& first, const In<double>& params, std::int64_t n);

// The matched filter for a frame of n tactels (ValueError when it does not fit the frame).
Filter filter_of(const In<double>& ax, const In<double>& ay_t, const In<std::int64_t>& bands,
                 std::int64_t n);

}  // namespace calib
}  // namespace tactiled
