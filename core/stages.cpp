#include "stages.hpp"

namespace tactiled {
void bind_all(pybind11::module_& m) {
    bind_impulse(m);
    bind_wire(m);
    bind_calibrate(m);
    bind_lines(m);
    bind_flexitac(m);
}
}  // namespace tactiled
