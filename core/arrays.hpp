// Small helpers the stages' bindings share: numpy arrays in (C order, converted to double when
// they are not) and out.  The stages' arithmetic itself takes plain pointers and sizes.
#pragma once
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>

#include <string>
#include <vector>

namespace tactiled {
namespace py = pybind11;

using Arr = py::array_t<double, py::array::c_style | py::array::forcecast>;
using IArr = py::array_t<long long, py::array::c_style | py::array::forcecast>;
using BArr = py::array_t<bool, py::array::c_style | py::array::forcecast>;

// A new 1-D float64 array holding v.
inline py::array_t<double> to_array(const std::vector<double>& v) {
    py::array_t<double> out(static_cast<py::ssize_t>(v.size()));
    double* d = out.mutable_data();
    for (size_t i = 0; i < v.size(); ++i) d[i] = v[i];
    return out;
}

// A new 2-D float64 array (rows x cols, row-major) holding v.
inline py::array_t<double> to_array(const std::vector<double>& v, py::ssize_t rows, py::ssize_t cols) {
    py::array_t<double> out({rows, cols});
    double* d = out.mutable_data();
    for (size_t i = 0; i < v.size(); ++i) d[i] = v[i];
    return out;
}

// A new 3-D float64 array holding v.
inline py::array_t<double> to_array(const std::vector<double>& v, py::ssize_t a, py::ssize_t b,
                                    py::ssize_t c) {
    py::array_t<double> out({a, b, c});
    double* d = out.mutable_data();
    for (size_t i = 0; i < v.size(); ++i) d[i] = v[i];
    return out;
}

// A 2-D strain frame of at least one tactel: its (rows, cols), else a ValueError.
inline void frame_shape(const Arr& s, long long& rows, long long& cols) {
    if (s.ndim() != 2 || s.shape(0) < 1 || s.shape(1) < 1)
        throw py::value_error("strain must be a 2-D array of at least one tactel");
    rows = s.shape(0);
    cols = s.shape(1);
}

// The extent of axis `axis` of an array (0 when it has fewer axes).
template <class A>
inline py::ssize_t dim(const A& a, int axis) {
    return a.ndim() > axis ? a.shape(axis) : 0;
}

// Inputs the kernels only read: converted to C-contiguous arrays of their type where they are
// not (a copy); outputs (plain py::array, checked by data_of) are never converted.
template <class T>
using In = py::array_t<T, py::array::c_style | py::array::forcecast>;

// An array argument as the kernels read it: C-contiguous, of dtype T, of `size` elements when
// given; `writable`: written in place (then a read-only array is refused too).  A wrong dtype
// or layout is a TypeError, never a silent copy that would lose the writes.
template <class T>
T* data_of(const py::array& a, const char* name, bool writable, py::ssize_t size = -1) {
    if (!py::isinstance<py::array_t<T>>(a) || !(a.flags() & py::array::c_style))
        throw py::type_error(std::string(name) + ": expected a C-contiguous " +
                             py::str(py::dtype::of<T>()).cast<std::string>() + " array, got " +
                             py::str(a.dtype()).cast<std::string>());
    if (size >= 0 && a.size() != size)
        throw py::value_error(std::string(name) + ": expected " + std::to_string(size) +
                              " values, got " + std::to_string(a.size()));
    if (writable && !a.writeable()) throw py::value_error(std::string(name) + ": array is read-only");
    return static_cast<T*>(const_cast<void*>(a.data()));
}
}  // namespace tactiled
