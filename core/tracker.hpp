// The tracker's per-frame arithmetic: a frame measured through a contact's linearisation, the
// per-parameter Kalman filters, the estimate's numbers by the delta method.  Python reference:
// tactiled/pipeline/kernels.py (same names, same arguments, same order of operations).
#pragma once
#include <cstdint>

namespace tactiled {
namespace tracker {

// Rows of a tracker's state table (6, k) and of its constants table (8, k).
enum StateRow { X = 0, V, PXX, PXV, PVV, DRIFT };
enum ConstRow { C_R = 0, C_MOVING, C_POINT, C_SD1, C_LOW, C_HIGH, C_LOG, C_LIN_SD };

// d = frame[index] - at; dp = gain (k, n) d; e = d - jacobian (n, k) dp, written to d.
// Returns chi2 = sum(e^2 weight).
double measure_window(const double* frame, const std::int64_t* index, std::int64_t n,
                      const double* at, const double* gain, std::int64_t k,
                      const double* jacobian, const double* weight, double* dp, double* d);

// measure_window, then the tracker's tests of the step (kernels.measure_point): true with dz
// turned into the measurement (the point plus the step, clipped to the box), false when the
// frame needs a fit.  d (n) receives the residual.
bool measure_point(const double* frame, const std::int64_t* index, std::int64_t n,
                   const double* at, const double* gain, std::int64_t k, const double* jacobian,
                   const double* weight, const double* c, double limit, std::int64_t ln_f,
                   double reset_sigma, double max_log_force_step, double* dz, double* d);

// The filters' step (kernels.filter_frame): s (6, k) in place, const (8, k).
std::int64_t filter_frame(const double* z, std::int64_t k, double* s, const double* c, double dt,
                          double acc_scale, double walk, bool fitted, double reset_sigma,
                          double drift_alpha, double drift_limit);

// The estimate's values and variances (kernels.estimate_numbers): values, var of 6 each.
std::int64_t estimate_numbers(std::int64_t model, const double* s, std::int64_t k, const double* c,
                              double dt, double excess, const double* corr, const double* sys,
                              bool has_sys, double lag_noise, double drift_alpha,
                              double* values, double* var, double& cov_rf);

// The state s (6, k) has moved from the linearisation point, or sharpened past it
// (kernels.moved_from_point).
bool moved_from_point(const double* s, std::int64_t k, const double* c, double sigmas,
                      double sharpen);
}  // namespace tracker
}  // namespace tactiled
