#include "stages.hpp"

namespace tactiled {
void bind_all(pybind11::module_& m) {
    bind_impulse(m);
}
}  // namespace tactiled
