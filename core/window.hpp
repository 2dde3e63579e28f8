// The fit window around the peak and the interpolated centre of pressure; Python reference:
// tactiled/fit/window.py (window_origin, _vertex, peak_centre, plain_window, plain_frame).
#pragma once

namespace tactiled {

// First index of a size-long window on an axis of `length` tactels containing `peak`; for an
// even size the extra tactel goes to the side whose neighbour is larger (the paper's 4x4
// "containing the peak").
long long window_origin(long long peak, long long size, long long length, double lower, double upper);

// Offset in [-0.5, 0.5] tactels of the vertex of the parabola through three samples (0 when
// they make no maximum).
double vertex(double lo, double mid, double hi);

// The sub-tactel centre (mm) of the peak at (m, n) of a rows x cols strain (row-major).
void peak_centre(const double* strain, long long rows, long long cols, long long m, long long n,
                 double dx, double dy, double& x, double& y);

// The peak and window of a frame with every tactel usable, in one pass: out = (usable, m, n,
// row0, col0, rows, cols); usable 0 when a strain is not finite or beyond max_strain.
void plain_window(const double* strain, long long rows, long long cols, long long size,
                  double max_strain, long long out[7]);
}  // namespace tactiled
