// What the framers' bindings share: a `feed` argument's bytes, a frame's counts as a new array,
// the counters in FramerStats' order, and the vendor framers' class (feed(bytes, host_time) ->
// (seq, device_time_us, raw) tuples), each in one place.
#pragma once

#include <pybind11/numpy.h>
#include <pybind11/stl.h>

#include <cstdint>
#include <cstring>
#include <tuple>
#include <utility>
#include <vector>

#include "lines.hpp"  // lines::Stats, the vendor framers' counters

namespace tactiled {
namespace binding {
namespace py = pybind11;

// The bytes of a `feed` argument (bytes, bytearray, a contiguous memoryview).
inline std::pair<const std::uint8_t*, std::size_t> bytes_of(const py::buffer& data) {
    py::buffer_info info = data.request();
    if (info.itemsize != 1 || info.ndim > 1 ||
        (info.ndim == 1 && info.shape[0] > 1 && info.strides[0] != 1))
        throw py::type_error("feed expects contiguous bytes");
    return {static_cast<const std::uint8_t*>(info.ptr), static_cast<std::size_t>(info.size)};
}

// rows * cols counts from `values` as a new (rows, cols) array.
template <class T>
py::array counts_array(const T* values, std::size_t rows, std::size_t cols) {
    py::array_t<T> raw({static_cast<py::ssize_t>(rows), static_cast<py::ssize_t>(cols)});
    std::memcpy(raw.mutable_data(), values, sizeof(T) * rows * cols);
    return std::move(raw);
}

// FramerStats' counters, in its field order.
inline std::vector<std::uint64_t> counters_of(const lines::Stats& s) {
    return {s.frames, s.bytes, s.resyncs, s.discarded, s.truncated, s.length_errors,
            s.oversize, s.crc_errors, s.parse_errors, s.ambiguous, s.lost, s.duplicated,
            s.restarts};
}

// A vendor framer (lines::Framer, flexitac::Framer) as Python sees it (robotiq.cpp's adds
// each frame's clock flag and extras).
template <class Framer, class Unit, class Count>
class Vendor {
public:
    Vendor(std::size_t rows, std::size_t cols, Framer framer)
        : rows_(rows), cols_(cols), framer_(std::move(framer)) {}

    std::vector<std::tuple<std::uint32_t, std::int64_t, py::array>> feed(const py::buffer& data,
                                                                         double host_time) {
        const auto bytes = bytes_of(data);
        units_.clear();
        counts_.clear();
        framer_.feed(bytes.first, bytes.second, host_time, units_, counts_);
        std::vector<std::tuple<std::uint32_t, std::int64_t, py::array>> batch;
        batch.reserve(units_.size());
        for (const auto& u : units_)
            batch.emplace_back(u.seq, u.device_time_us,
                               counts_array(counts_.data() + u.offset, rows_, cols_));
        return batch;
    }
    void reset() { framer_.reset(); }
    std::size_t buffered() const { return framer_.buffered(); }
    std::vector<std::uint64_t> counters() const { return counters_of(framer_.stats()); }

    // The class's methods but its constructor (each binding adds its own).
    static py::class_<Vendor> bind(py::module_& m, const char* name, const char* doc) {
        return py::class_<Vendor>(m, name, doc)
            .def("feed", &Vendor::feed, py::arg("data"), py::arg("host_time"),
                 "The frames `data` completes: (seq, device_time_us, raw (rows, cols)) tuples.")
            .def("reset", &Vendor::reset)
            .def_property_readonly("buffered", &Vendor::buffered)
            .def("counters", &Vendor::counters, "FramerStats' counters, in its field order.");
    }

private:
    std::size_t rows_, cols_;
    Framer framer_;
    std::vector<Unit> units_;
    std::vector<Count> counts_;
};

}  // namespace binding
}  // namespace tactiled
