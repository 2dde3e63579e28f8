// The stages' binding entry points. A stage adds its `bind_<stage>(py::module_&)` here and to
// bind_all in stages.cpp.
#pragma once
#include <pybind11/pybind11.h>

namespace tactiled {
void bind_impulse(pybind11::module_& m);
void bind_wire(pybind11::module_& m);
void bind_calibrate(pybind11::module_& m);
void bind_lines(pybind11::module_& m);
void bind_flexitac(pybind11::module_& m);
void bind_robotiq(pybind11::module_& m);
void bind_eccentricity(pybind11::module_& m);
void bind_hertz(pybind11::module_& m);
void bind_models(pybind11::module_& m);
void bind_quadrature(pybind11::module_& m);
void bind_lsq(pybind11::module_& m);
void bind_line(pybind11::module_& m);
void bind_search(pybind11::module_& m);
void bind_window(pybind11::module_& m);
void bind_start(pybind11::module_& m);
void bind_flatfield(pybind11::module_& m);
void bind_tracker(pybind11::module_& m);
void bind_linewindow(pybind11::module_& m);
void bind_halfspace(pybind11::module_& m);
void bind_regions(pybind11::module_& m);
void bind_zero_run(pybind11::module_& m);
void bind_track_step(pybind11::module_& m);
void bind_track_run(pybind11::module_& m);
void bind_all(pybind11::module_& m);
}  // namespace tactiled
