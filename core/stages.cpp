#include "stages.hpp"

namespace tactiled {
void bind_all(pybind11::module_& m) {
    bind_impulse(m);
    bind_wire(m);
    bind_calibrate(m);
    bind_lines(m);
    bind_flexitac(m);
    bind_robotiq(m);
    bind_eccentricity(m);
    bind_hertz(m);
    bind_models(m);
    bind_quadrature(m);
    bind_lsq(m);
    bind_line(m);
    bind_search(m);
    bind_window(m);
    bind_start(m);
    bind_flatfield(m);
    bind_tracker(m);
    bind_linewindow(m);
    bind_halfspace(m);
    bind_regions(m);
    bind_zero_run(m);
    bind_track_step(m);
    bind_track_run(m);
}
}  // namespace tactiled
