// Complex arithmetic as CPython does it (Objects/complexobject.c: _Py_c_prod, _Py_c_quot, a
// float operand taken as complex(x, 0.0)), so the line contact's residues give the Python
// reference's numbers to the bit, signed zeros included.
#pragma once

namespace tactiled {

struct Cx {
    double re, im;
};

inline Cx cx(double x) { return {x, 0.0}; }
inline Cx operator+(Cx a, Cx b) { return {a.re + b.re, a.im + b.im}; }
inline Cx operator-(Cx a, Cx b) { return {a.re - b.re, a.im - b.im}; }
inline Cx operator*(Cx a, Cx b) { return {a.re * b.re - a.im * b.im, a.re * b.im + a.im * b.re}; }
// CPython's _Py_c_quot: Smith's division, the larger of b's parts divided out first.
inline Cx operator/(Cx a, Cx b) {
    const double abs_re = b.re < 0 ? -b.re : b.re;
    const double abs_im = b.im < 0 ? -b.im : b.im;
    if (abs_re >= abs_im) {
        if (abs_re == 0.0) return {0.0, 0.0};  // (CPython raises ZeroDivisionError)
        const double ratio = b.im / b.re;
        const double denom = b.re + b.im * ratio;
        return {(a.re + a.im * ratio) / denom, (a.im - a.re * ratio) / denom};
    }
    if (abs_im >= abs_re) {
        const double ratio = b.re / b.im;
        const double denom = b.re * ratio + b.im;
        return {(a.re * ratio + a.im) / denom, (a.im * ratio - a.re) / denom};
    }
    const double nan = 0.0 / 0.0;
    return {nan, nan};
}
inline Cx operator+(Cx a, double b) { return a + cx(b); }
inline Cx operator+(double a, Cx b) { return cx(a) + b; }
inline Cx operator-(Cx a, double b) { return a - cx(b); }
inline Cx operator-(double a, Cx b) { return cx(a) - b; }
inline Cx operator*(Cx a, double b) { return a * cx(b); }
inline Cx operator*(double a, Cx b) { return cx(a) * b; }
inline Cx operator/(Cx a, double b) { return a / cx(b); }
inline Cx operator/(double a, Cx b) { return cx(a) / b; }
inline Cx operator-(Cx a) { return {-a.re, -a.im}; }

const Cx J1{0.0, 1.0};  // Python's 1j
}  // namespace tactiled
