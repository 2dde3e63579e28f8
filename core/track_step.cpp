// A tracked contact's frame in one call (TrackStep.step): what Tracker.step does for a frame it
// measures, on the tracker's own arrays (checked once, when the tracker adopts a linearisation
// or restarts its filters), so a frame costs one call into the core, not a dozen numpy calls.
// Python reference: tactiled/pipeline/kernels.py's TrackStep.
#include "track_step.hpp"

#include <pybind11/numpy.h>

#include <cmath>
#include <limits>
#include <string>
#include <vector>

#include "arrays.hpp"
#include "pymath.hpp"
#include "stages.hpp"
#include "tracker.hpp"

namespace py = pybind11;

namespace tactiled {
namespace track {

void lag_variance(const double* lag, std::int64_t k, double weight, double significant,
                  double* out) {
    const double sig2 = significant * significant;
    for (std::int64_t i = 0; i < k; ++i) {
        const double m = lag[i], noise = lag[k + i] * weight / (2.0 - weight);
        out[i] = m * m > sig2 * noise ? m * m : 0.0;
    }
}

}  // namespace track

void bind_track_step(py::module_& m) {
    using track::TrackStep;
    py::class_<TrackStep>(m, "TrackStep",
                          "One tracked contact's frame in one call (kernels.TrackStep).")
        .def(py::init<py::array, py::array, py::array, py::array, py::array, py::array,
                      py::array, py::array, py::array, py::array, py::array, py::array,
                      py::array, py::tuple>(),
             py::arg("s"), py::arg("lag"), py::arg("c"), py::arg("z"), py::arg("ebuf"),
             py::arg("index"), py::arg("at"), py::arg("gain"), py::arg("jacobian"),
             py::arg("weight"), py::arg("corr"), py::arg("sys"), py::arg("lag_key"),
             py::arg("constants"))
        .def("estimate", &TrackStep::estimate, py::arg("dt"), py::arg("excess"))
        .def("measure", &TrackStep::measure, py::arg("frame"), py::arg("at"))
        .def("advance", &TrackStep::advance, py::arg("dt"), py::arg("fitted") = false)
        .def("step", &TrackStep::step, py::arg("frame"), py::arg("dt"))
        .def_property_readonly("s", &TrackStep::s)
        .def_property_readonly("lag", &TrackStep::lag)
        .def_property_readonly("z", &TrackStep::z)
        .def_property_readonly("ebuf", &TrackStep::ebuf);
}
}  // namespace tactiled
