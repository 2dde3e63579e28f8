// Python's float semantics where C++'s differ, so the core gives the reference's numbers.
#pragma once
#include <cmath>

namespace tactiled {
// Python's float `x % y`: the result takes the divisor's sign (CPython's float_rem).
inline double py_mod(double x, double y) {
    double mod = std::fmod(x, y);
    if (mod != 0.0) {
        if ((y < 0.0) != (mod < 0.0)) mod += y;
    } else {
        mod = std::copysign(0.0, y);
    }
    return mod;
}

// Python's max(a, b) / min(a, b): the first unless the second is strictly larger / smaller
// (so a NaN first argument is kept, as CPython keeps it).
inline double py_max(double a, double b) { return b > a ? b : a; }
inline double py_min(double a, double b) { return b < a ? b : a; }
}  // namespace tactiled
