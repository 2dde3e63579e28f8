// tactiled._core: the Python bindings of the compiled core. Each stage lives in its own
// core/<stage>.cpp with its header; this file only binds them (one `bind_<stage>` call each).
#include <pybind11/pybind11.h>

#include "stages.hpp"

namespace py = pybind11;

PYBIND11_MODULE(_core, m) {
    m.doc() = "tactiled's compiled core (C++); tactiled.native selects it or the Python reference.";
    m.attr("ABI") = 1;  // bumped when a binding's signature changes; tactiled.native checks it
    tactiled::bind_all(m);
}
