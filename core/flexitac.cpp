// The FlexiTac framer (core/flexitac.hpp) and its bindings.
#include "flexitac.hpp"

#include <cmath>
#include <cstring>
#include <tuple>

#include "framer_binding.hpp"
#include "stages.hpp"

namespace py = pybind11;

namespace tactiled {
namespace flexitac {

long Framer::find(std::size_t from, std::size_t to) const {
    to = to < size() ? to : size();
    for (std::size_t k = from; k + 2 <= to; ++k)
        if (at(k) == 0xAA && at(k + 1) == 0x55) return static_cast<long>(k);
    return -1;
}

void Framer::reset() {
    clear_held();
    synced_ = false;
}

bool Framer::find_phase() {
    const long first = find(0, size());
    if (first < 0) {
        const std::size_t keep = (size() > 0 && at(size() - 1) == 0xAA) ? 1 : 0;
        drop(size() - keep);
        return false;
    }
    drop(static_cast<std::size_t>(first));
    if (size() < 2 * period_ + 1) return false;  // every phase of one span checked
    std::size_t phases = 0, phase = 0;
    long k = 0;
    while (k >= 0 && static_cast<std::size_t>(k) < period_) {
        const std::size_t next = static_cast<std::size_t>(k) + period_;
        if (marker_at(next) || torn_marker(next)) {
            if (phases++ == 0) phase = static_cast<std::size_t>(k);
        }
        k = find(static_cast<std::size_t>(k) + 1, period_ + 1);
    }
    if (phases == 1) {
        drop(phase);
        synced_ = true;
    } else if (phases == 0) {
        const long next = find(1, size());
        drop(next > 0 ? static_cast<std::size_t>(next) : size() - 1);
    } else {
        ++stats_.ambiguous;
        drop(period_);
    }
    return true;
}

bool Framer::torn_marker(std::size_t i) const {
    // 0xAA at i then a whole marker: the device reset right after a marker's first byte, so
    // the frame before i is whole (flexitac.py's _torn_marker)
    return i < size() && at(i) == 0xAA && marker_at(i + 1);
}

void Framer::emit(double host_time, std::vector<Frame>& out, std::vector<std::uint16_t>& counts) {
    Frame f{seq_++, host_clock_us(host_time), counts.size()};
    for (std::size_t c = 0; c < cells_; ++c) counts.push_back(at(2 + c));
    out.push_back(f);
    accepted();
    consume(period_);
}

void Framer::feed(const std::uint8_t* data, std::size_t n, double host_time,
                  std::vector<Frame>& out, std::vector<std::uint16_t>& counts) {
    if (n == 0) return;
    append(data, n);
    while (true) {
        if (synced_) {
            if (size() < period_ + 2) break;
            if (marker_at(period_)) {
                emit(host_time, out, counts);
                continue;
            }
            // a marker torn after its first byte? one more byte tells
            if (at(period_) == 0xAA && size() < period_ + 3) break;
            if (torn_marker(period_)) {
                emit(host_time, out, counts);
                ++stats_.truncated;  // the lone 0xAA is the torn unit
                in_error_ = true;
                drop(1);
                continue;
            }
            synced_ = false;
            const long early = find(2, period_ + 1);
            if (early >= 0)
                ++stats_.truncated;
            else
                ++stats_.length_errors;
            in_error_ = true;
            drop(early >= 0 ? static_cast<std::size_t>(early) : period_);
            continue;
        }
        if (!find_phase()) break;
    }
    compact();
}

}  // namespace flexitac

void bind_flexitac(py::module_& m) {
    using Bound = binding::Vendor<flexitac::Framer, flexitac::Frame, std::uint16_t>;
    Bound::bind(m, "FlexiTacFramer", "FlexiTac's marker framing (tactiled_drivers.flexitac's core).")
        .def(py::init([](std::size_t rows, std::size_t cols) {
                 if (!(rows >= 1 && cols >= 1 && rows * cols <= 4096))
                     throw py::value_error("rows * cols: need 1..4096");
                 return Bound(rows, cols, flexitac::Framer(rows, cols));
             }),
             py::arg("rows"), py::arg("cols"));
}
}  // namespace tactiled
