// Bindings of the impulse-response stage (core/impulse.hpp).
#include "impulse.hpp"

#include <pybind11/numpy.h>

#include "stages.hpp"

namespace py = pybind11;

namespace tactiled {
namespace {
py::array_t<double> line_response_array(
    py::array_t<double, py::array::c_style | py::array::forcecast> u, double depth, double nu) {
    py::array_t<double> out(u.request().shape);
    const auto n = u.size();
    const double* src = u.data();
    double* dst = out.mutable_data();
    for (py::ssize_t i = 0; i < n; ++i) dst[i] = line_response(src[i], depth, nu);
    return out;
}
}  // namespace

void bind_impulse(py::module_& m) {
    m.def("line_response", &line_response_array, py::arg("u"), py::arg("depth"), py::arg("nu"),
          "h(u) in 1/mm for offsets u in mm (tactiled.physics.impulse.line_response).");
}
}  // namespace tactiled
