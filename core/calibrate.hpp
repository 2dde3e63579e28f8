// The calibration stage's per-frame arithmetic (lookup table, zeroing, hysteresis, the
// detector's matched filter).  Python reference: tactiled/calibration/fused_reference.py (numba
// kernels of the same names and arguments); tests/native/test_calibrate_core.py holds the two
// bit-equal.  min and max are Python's (the first argument unless the second compares
// strictly beyond it), as numba compiles them, so a NaN goes where it goes there.
#pragma once

#include <cstdint>

namespace tactiled {
namespace calib {

inline double py_min(double a, double b) { return b < a ? b : a; }
inline double py_max(double a, double b) { return b > a ? b : a; }

// The table's segments (tactiled.calibration.segments.Segments' arrays).
struct Segments {
    const double* offset;   // (T,)
    const double* breaks;   // (NB,)
    std::int64_t nb;
    const std::int64_t* first;  // (T + 1,)
    const double* params;   // (5, NP) row-major
    std::int64_t np;
};

// The matched filter's matrices and bands (ContactDetector._ax, _ay_t, _bands).
struct Filter {
    const double* ax;     // (nu, rows)
    const double* ay_t;   // (cols, nv)
    const std::int64_t* bands;  // (4, nbands)
    std::int64_t nu, rows, cols, nv, nbands;
};

struct ZeroResult {
    std::int64_t state;
    double statistic, peak;
};

// One frame's counts (as doubles, T of them) -> z; see fused_reference.zero_frame.
template <class Raw>
ZeroResult zero_frame(const Raw* raw, std::int64_t n, const Segments& seg, const double* baseline,
                      double* peak, double fraction, double decay, double floor, double margin,
                      bool active, const Filter& f, double* z, double* residual, double* tmap,
                      double* m /* nu * cols scratch */);

void follow_baseline(double* baseline, double* z, std::int64_t n, double weight, double limit,
                     bool clip);

// The detector's running mean of its last `average` filter maps of p values (ring: average x p,
// the oldest at `head` once full; total: their sum); tmap the newest.  Returns the statistic of
// the mean; see fused_reference.average_maps.
double average_maps(double* ring, double* total, const double* tmap, std::int64_t average,
                    std::int64_t p, std::int64_t& count, std::int64_t& head);

}  // namespace calib
}  // namespace tactiled
