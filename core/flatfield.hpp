// The flat field's per-fit accumulation; Python reference: tactiled/fit/flatfield.py
// (_accumulate).
#pragma once

namespace tactiled {

// Add one fit, weighted w, to a window's sums ata (3k x 3k) and atb (3k):
// X^T X = E^T M E and X^T (r + X u) = E^T (r + M E u) (M, the residual operator, a symmetric
// projection, k x k; E = [diag(-m), diag(jx), diag(jy)]; u[idx] the corrections the fit ran
// with).  Returns |r0|^2 - tr M of the uncorrected residuals r0, or NaN (adding nothing) when
// a number of the fit is not finite.
double accumulate(double* ata, double* atb, const double* resid_op, const double* m,
                  const double* jx, const double* jy, const double* r, const double* u,
                  const long long* idx, long long k, double w);
}  // namespace tactiled
