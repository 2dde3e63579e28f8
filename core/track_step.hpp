// A tracked contact's frame in one call: measured through the contact's linearisation, its
// residual buffered, the per-parameter filters stepped, the lag's running means updated.
// Python reference: tactiled/pipeline/kernels.py's TrackStep (same arguments, same order of
// operations; tests/native/test_track_step.py).
#pragma once
#include <cstdint>

namespace tactiled {
namespace track {

// TrackStep.advance's answers besides 0 (updated) and a jump's bit mask (> 0)
constexpr std::int64_t STEP_UNMEASURED = -1;
constexpr std::int64_t STEP_REFIT = -2;
constexpr std::int64_t STEP_RESTART = -3;

// The scalar constants (kernels.TRACK_CONSTANTS), in that order.
struct Constants {
    double limit;
    std::int64_t ln_f;
    double reset_sigma, max_log_force_step;
    std::int64_t beta_i;
    double beta_sign, memory_s, hold_s, drift_alpha, drift_limit, lag_weight, lag_significant,
        max_gap_s;
    std::int64_t model;
    bool has_sys;
    double lag_noise;
};
constexpr int CONSTANT_COUNT = 16;

// Per parameter, the lag's variance (kernels.lag_variance): lag (2, k) -> out (k).
void lag_variance(const double* lag, std::int64_t k, double weight, double significant,
                  double* out);
}  // namespace track
}  // namespace tactiled
