// The fit window (window.hpp) and its bindings.
#include "window.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

#include "arrays.hpp"
#include "pymath.hpp"
#include "stages.hpp"

namespace tactiled {

long long window_origin(long long peak, long long size, long long length, double lower, double upper) {
    if (size >= length) return 0;
    // Python's floor division: (size - 1) // 2 with size >= 1
    long long start = peak - (size - 1) / 2;
    if (size % 2 == 0 && upper < lower) start -= 1;
    return std::min(std::max(start, 0LL), length - size);
}

double vertex(double lo, double mid, double hi) {
    const double den = lo - 2.0 * mid + hi;
    if (!(den < 0.0)) return 0.0;  // not a maximum: stay on the peak tactel
    return py_min(py_max(0.5 * (lo - hi) / den, -0.5), 0.5);
}

void peak_centre(const double* s, long long rows, long long cols, long long m, long long n,
                 double dx, double dy, double& x, double& y) {
    const double c = s[m * cols + n];
    const double lo_x = m > 0 ? s[(m - 1) * cols + n] : c;
    const double hi_x = m < rows - 1 ? s[(m + 1) * cols + n] : c;
    const double lo_y = n > 0 ? s[m * cols + n - 1] : c;
    const double hi_y = n < cols - 1 ? s[m * cols + n + 1] : c;
    x = (static_cast<double>(m) + vertex(lo_x, c, hi_x)) * dx;
    y = (static_cast<double>(n) + vertex(lo_y, c, hi_y)) * dy;
}

void plain_window(const double* s, long long rows, long long cols, long long size,
                  double max_strain, long long out[7]) {
    const double NINF = -std::numeric_limits<double>::infinity();
    double best = NINF;
    long long m = 0, n = 0;
    for (int i = 0; i < 7; ++i) out[i] = 0;
    for (long long i = 0; i < rows; ++i)
        for (long long j = 0; j < cols; ++j) {
            const double v = s[i * cols + j];
            if (!(std::fabs(v) <= max_strain)) return;
            if (v > best) {
                best = v;
                m = i;
                n = j;
            }
        }
    const long long nr = std::min(size, rows), nc = std::min(size, cols);
    const double lo_r = m > 0 ? s[(m - 1) * cols + n] : NINF;
    const double hi_r = m + 1 < rows ? s[(m + 1) * cols + n] : NINF;
    const double lo_c = n > 0 ? s[m * cols + n - 1] : NINF;
    const double hi_c = n + 1 < cols ? s[m * cols + n + 1] : NINF;
    out[0] = 1;
    out[1] = m;
    out[2] = n;
    out[3] = window_origin(m, nr, rows, lo_r, hi_r);
    out[4] = window_origin(n, nc, cols, lo_c, hi_c);
    out[5] = nr;
    out[6] = nc;
}

namespace {
void check_peak(long long rows, long long cols, long long m, long long n) {
    if (m < 0 || m >= rows || n < 0 || n >= cols) throw py::index_error("peak outside the frame");
}
}  // namespace

void bind_window(py::module_& m) {
    m.def("window_origin", &window_origin);
    m.def("peak_centre", [](Arr strain, long long mm, long long n, double dx, double dy) {
        long long rows, cols;
        frame_shape(strain, rows, cols);
        check_peak(rows, cols, mm, n);
        double x, y;
        peak_centre(strain.data(), rows, cols, mm, n, dx, dy, x, y);
        return py::make_tuple(x, y);
    });
    m.def("plain_window", [](Arr strain, long long size, double max_strain) {
        long long rows, cols, o[7];
        frame_shape(strain, rows, cols);
        plain_window(strain.data(), rows, cols, size, max_strain, o);
        return py::make_tuple(o[0], o[1], o[2], o[3], o[4], o[5], o[6]);
    });
    m.def("plain_frame", [](Arr strain, long long size, double max_strain, double min_peak, double sigma) {
        long long rows, cols, o[7];
        frame_shape(strain, rows, cols);
        const double* s = strain.data();
        plain_window(s, rows, cols, size, max_strain, o);
        long long usable = o[0];
        const long long mm = o[1], n = o[2], r0 = o[3], c0 = o[4], nr = o[5], nc = o[6];
        const double peak = s[mm * cols + n];
        if (!(peak > min_peak)) usable = 0;
        const py::ssize_t k = usable ? nr * nc : 0;
        py::array_t<double> target(k), inv_scale(k), zdata(k);
        py::array_t<bool> valid(k);
        if (usable) {
            const double inv = 1.0 / peak;
            for (long long i = 0; i < nr; ++i)
                for (long long j = 0; j < nc; ++j) {
                    const long long q = i * nc + j;
                    const double t = s[(r0 + i) * cols + c0 + j];
                    target.mutable_data()[q] = t;
                    inv_scale.mutable_data()[q] = inv;
                    zdata.mutable_data()[q] = t / sigma;
                }
        }
        for (py::ssize_t q = 0; q < k; ++q) valid.mutable_data()[q] = true;
        return py::make_tuple(usable, mm, n, r0, c0, nr, nc, peak, target, valid, inv_scale, zdata);
    });
}
}  // namespace tactiled
