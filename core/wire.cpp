// The wire format's decoder (core/wire.hpp) and its bindings.
#include "wire.hpp"

#include <pybind11/numpy.h>
#include <pybind11/stl.h>

#include <array>
#include <cstring>
#include <tuple>

#include "framer_binding.hpp"
#include "stages.hpp"

namespace py = pybind11;

namespace tactiled {
namespace wire {
namespace {
std::array<std::uint32_t, 256> make_table() {
    std::array<std::uint32_t, 256> t{};
    for (std::uint32_t i = 0; i < 256; ++i) {
        std::uint32_t c = i;
        for (int k = 0; k < 8; ++k) c = (c & 1u) ? (0xEDB88320u ^ (c >> 1)) : (c >> 1);
        t[i] = c;
    }
    return t;
}
const std::array<std::uint32_t, 256> CRC_TABLE = make_table();

template <class T>
T le(const std::uint8_t* p) {
    T v = 0;
    for (std::size_t k = 0; k < sizeof(T); ++k) v |= static_cast<T>(p[k]) << (8 * k);
    return v;
}

// frames.py's _cobs_decode: the decoded bytes (so far) into `out`; whether the chunk is valid
bool cobs_decode(const std::uint8_t* chunk, std::size_t n, std::vector<std::uint8_t>& out) {
    out.clear();
    if (n == 0) return false;
    out.reserve(n);
    // Groups: code byte at i, then code-1 data bytes; a zero follows unless the code is 0xFF.
    std::size_t i = 0;
    std::uint8_t code = chunk[0];
    while (code) {
        const std::size_t j = i + code;
        if (j >= n) break;
        out.insert(out.end(), chunk + i + 1, chunk + j);
        if (code != 0xFF) out.push_back(0);
        i = j;
        code = chunk[j];
    }
    // the last (or broken) group: its data bytes as far as they go
    if (i + 1 < n) out.insert(out.end(), chunk + i + 1, chunk + n);
    return code != 0 && i + code == n;
}
}  // namespace

std::uint32_t crc32(const std::uint8_t* data, std::size_t n) {
    std::uint32_t c = 0xFFFFFFFFu;
    for (std::size_t k = 0; k < n; ++k) c = CRC_TABLE[(c ^ data[k]) & 0xFFu] ^ (c >> 8);
    return c ^ 0xFFFFFFFFu;
}

// frames.py's _values: the counts a header declares, 0 for a header this format does not carry
static std::size_t header_values(int version, std::size_t axes, std::size_t rows, std::size_t cols) {
    if (version == VERSION) return rows * cols;
    if (version == VERSION_AXES && (axes == 1 || axes == 3)) return rows * cols * axes;
    return 0;
}

Verdict parse(const std::uint8_t* chunk, std::size_t n, std::vector<std::uint8_t>& data,
              Decoded& frame, std::vector<std::uint16_t>& counts) {
    const bool cobs_ok = cobs_decode(chunk, n, data);
    const std::size_t m = data.size();
    if (m < HEADER_LEN + CRC_LEN) return Verdict::truncated;
    const std::uint8_t* d = data.data();
    const int version = d[0];
    const std::size_t axes = d[1], rows = d[16], cols = d[17];
    const std::size_t values = header_values(version, axes, rows, cols);
    const std::size_t expected = HEADER_LEN + 2 * values + CRC_LEN;
    const std::uint32_t crc = le<std::uint32_t>(d + m - CRC_LEN);
    const bool plausible = 0 < values && values <= MAX_TACTELS;
    if (cobs_ok && crc32(d, m - CRC_LEN) == crc) {
        if (version != VERSION && version != VERSION_AXES) return Verdict::version_errors;
        if (!plausible || m != expected) return Verdict::length_errors;
        frame.sensor_id = le<std::uint16_t>(d + 2);
        frame.seq = le<std::uint32_t>(d + 4);
        frame.device_time_us = le<std::uint64_t>(d + 8);
        frame.rows = static_cast<std::uint8_t>(rows);
        frame.cols = static_cast<std::uint8_t>(cols);
        frame.axes = static_cast<std::uint8_t>(version == VERSION ? 1 : axes);
        frame.offset = counts.size();
        const std::uint8_t* p = d + HEADER_LEN;
        for (std::size_t k = 0; k < values; ++k)
            counts.push_back(static_cast<std::uint16_t>(p[2 * k] | (p[2 * k + 1] << 8)));
        return Verdict::frame;
    }
    if (plausible && m < expected) return Verdict::truncated;
    return cobs_ok ? Verdict::crc_errors : Verdict::cobs_errors;
}

void Decoder::reset() {
    buf_.clear();
    discarding_ = false;
    in_error_ = false;
    last_seq_.clear();
}

void Decoder::check_bound() {
    if (buf_.size() > MAX_ENCODED_LEN) {
        buf_.clear();
        discarding_ = true;
        reject(stats_.oversize);
    }
}

bool Decoder::accept(const Decoded& f) {
    auto it = last_seq_.find(f.sensor_id);
    if (it != last_seq_.end()) {
        const std::uint32_t step = f.seq - it->second;  // uint32 wrap-around
        if (step == 0) {
            ++stats_.duplicated;
            return false;
        }
        if (step < 0x80000000u)
            stats_.lost += step - 1;
        else
            ++stats_.restarts;
        it->second = f.seq;
    } else {
        last_seq_.emplace(f.sensor_id, f.seq);
    }
    ++stats_.frames;
    if (in_error_) {
        ++stats_.resyncs;
        in_error_ = false;
    }
    return true;
}

void Decoder::chunk(const std::uint8_t* c, std::size_t n, std::vector<Decoded>& out,
                    std::vector<std::uint16_t>& counts) {
    if (n == 0) return;  // leading, doubled or idle 0x00: not an error
    if (n > MAX_ENCODED_LEN) {
        reject(stats_.oversize);
        return;
    }
    Decoded f{};
    const std::size_t mark = counts.size();
    switch (parse(c, n, scratch_, f, counts)) {
        case Verdict::frame:
            if (accept(f))
                out.push_back(f);
            else
                counts.resize(mark);
            return;
        case Verdict::crc_errors: reject(stats_.crc_errors); return;
        case Verdict::length_errors: reject(stats_.length_errors); return;
        case Verdict::version_errors: reject(stats_.version_errors); return;
        case Verdict::cobs_errors: reject(stats_.cobs_errors); return;
        case Verdict::truncated: reject(stats_.truncated); return;
    }
}

void Decoder::feed(const std::uint8_t* data, std::size_t n, std::vector<Decoded>& out,
                   std::vector<std::uint16_t>& counts) {
    if (n == 0) return;
    stats_.bytes += n;
    const std::uint8_t* end = data + n;
    if (discarding_) {
        const auto* z = static_cast<const std::uint8_t*>(std::memchr(data, 0, n));
        if (z == nullptr) return;
        data = z + 1;
        discarding_ = false;
    }
    const auto* z = static_cast<const std::uint8_t*>(
        data < end ? std::memchr(data, 0, static_cast<std::size_t>(end - data)) : nullptr);
    if (z == nullptr) {
        buf_.insert(buf_.end(), data, end);
        check_bound();
        return;
    }
    // the first chunk completes the buffered bytes
    if (buf_.empty()) {
        chunk(data, static_cast<std::size_t>(z - data), out, counts);
    } else {
        buf_.insert(buf_.end(), data, z);
        std::vector<std::uint8_t> first;
        first.swap(buf_);
        chunk(first.data(), first.size(), out, counts);
    }
    const std::uint8_t* start = z + 1;
    while (true) {
        const auto* next = static_cast<const std::uint8_t*>(
            start < end ? std::memchr(start, 0, static_cast<std::size_t>(end - start)) : nullptr);
        if (next == nullptr) break;
        chunk(start, static_cast<std::size_t>(next - start), out, counts);
        start = next + 1;
    }
    buf_.assign(start, end);
    // the unterminated tail comes after every complete chunk: rejected only now
    check_bound();
}

}  // namespace wire

namespace {
using Batch = std::vector<std::tuple<std::uint32_t, std::uint64_t, std::uint16_t, py::array>>;

// A 3-axis frame's counts, uint16 (rows, cols, axes).
py::array taxel_array(const std::uint16_t* values, std::size_t rows, std::size_t cols,
                      std::size_t axes) {
    py::array_t<std::uint16_t> out({static_cast<py::ssize_t>(rows), static_cast<py::ssize_t>(cols),
                                    static_cast<py::ssize_t>(axes)});
    std::memcpy(out.mutable_data(), values, sizeof(std::uint16_t) * rows * cols * axes);
    return std::move(out);
}

// Frames of one feed as (seq, device_time_us, sensor_id, counts) tuples: counts uint16
// (rows, cols) for a 1-axis frame, (rows, cols, 3) for a 3-axis one.
Batch to_batch(const std::vector<wire::Decoded>& frames, const std::vector<std::uint16_t>& counts) {
    Batch batch;
    batch.reserve(frames.size());
    for (const auto& f : frames) {
        const std::uint16_t* values = counts.data() + f.offset;
        batch.emplace_back(f.seq, f.device_time_us, f.sensor_id,
                           f.axes == 1 ? binding::counts_array(values, f.rows, f.cols)
                                       : taxel_array(values, f.rows, f.cols, f.axes));
    }
    return batch;
}

class PyDecoder {
public:
    Batch feed(py::buffer data) {
        const auto bytes = binding::bytes_of(data);
        frames_.clear();
        counts_.clear();
        // (the lock is kept: a few microseconds of work, and the serial read thread would
        // take it; tactiled/calibration/fused.py says what that cost)
        dec_.feed(bytes.first, bytes.second, frames_, counts_);
        return to_batch(frames_, counts_);
    }
    void reset() { dec_.reset(); }
    std::size_t buffered() const { return dec_.buffered(); }
    std::tuple<std::uint64_t, std::uint64_t, std::uint64_t, std::uint64_t, std::uint64_t,
               std::uint64_t, std::uint64_t, std::uint64_t, std::uint64_t, std::uint64_t,
               std::uint64_t, std::uint64_t>
    counters() const {
        const auto& s = dec_.stats();
        return {s.frames, s.bytes, s.crc_errors, s.length_errors, s.version_errors,
                s.cobs_errors, s.truncated, s.oversize, s.lost, s.duplicated, s.restarts,
                s.resyncs};
    }

private:
    wire::Decoder dec_;
    std::vector<wire::Decoded> frames_;
    std::vector<std::uint16_t> counts_;
};
}  // namespace

void bind_wire(py::module_& m) {
    py::class_<PyDecoder>(m, "WireDecoder",
                          "The wire format's stream decoder (tactiled.frames.FrameDecoder's core).")
        .def(py::init<>())
        .def("feed", &PyDecoder::feed, py::arg("data"),
             "The frames `data` completes: (seq, device_time_us, sensor_id, counts) tuples "
             "(counts (rows, cols), or (rows, cols, 3) for a 3-axis frame).")
        .def("reset", &PyDecoder::reset)
        .def_property_readonly("buffered", &PyDecoder::buffered)
        .def("counters", &PyDecoder::counters, "DecoderStats' counters, in its field order.");
    m.def("crc32", [](py::bytes b) {
        std::string s = b;
        return wire::crc32(reinterpret_cast<const std::uint8_t*>(s.data()), s.size());
    }, "zlib.crc32 of `b`.");
}
}  // namespace tactiled
