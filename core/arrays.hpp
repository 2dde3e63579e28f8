// Small helpers the stages' bindings share: numpy arrays in (C order, converted to double when
// they are not) and out.  The stages' arithmetic itself takes plain pointers and sizes.
#pragma once
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>

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
}  // namespace tactiled
