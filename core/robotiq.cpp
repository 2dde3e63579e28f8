// The Robotiq framer (core/robotiq.hpp) and its bindings.  Each step mirrors RobotiqFramer's
// (drivers/tactiled_drivers/robotiq.py) of the same name.
#include "robotiq.hpp"

#include <cstring>
#include <limits>
#include <tuple>

#include "framer_binding.hpp"
#include "stages.hpp"

namespace py = pybind11;

namespace tactiled {
namespace robotiq {
namespace {
constexpr std::uint8_t STATIC = 0x10, TIMESTAMP = 0x70;

// payload bytes of a field kind (high nibble of its type byte; the timestamp's 2), 0: unknown
inline std::size_t field_bytes(std::uint8_t kind) {
    switch (kind) {
        case 0x10: return 2 * ROWS * COLS;
        case 0x20: case 0x60: case 0x70: return 2;
        case 0x30: case 0x40: case 0x50: return 6;
        default: return 0;
    }
}

// The extras' index of a field kind (dynamic 0x20 .. temperature 0x60).
inline Kind extra_of(std::uint8_t kind) { return static_cast<Kind>((kind >> 4) - 2); }

// _fields: the fields of data[i:n], appended to `out` (if given), the first parse in the
// reference's order (a timestamp as 2 bytes, then as 8); false, `out` as it was, if they do
// not end exactly at n.
bool parse_fields(const std::uint8_t* data, std::size_t n, std::size_t i,
                  std::vector<Field>* out) {
    const std::size_t mark = out ? out->size() : 0;
    while (i < n) {
        const std::uint8_t kind = data[i] & 0xF0, finger = (data[i] >> 2) & 0x03;
        const std::size_t size = field_bytes(kind);
        if (size == 0 || i + 1 + size > n) break;
        if (kind == TIMESTAMP && i + 9 <= n) {
            if (out) out->push_back({kind, finger, i + 1, 2});
            if (parse_fields(data, n, i + 3, out)) return true;
            if (out) out->back().size = 8;
            if (parse_fields(data, n, i + 9, out)) return true;
            break;
        }
        if (out) out->push_back({kind, finger, i + 1, size});
        i += 1 + size;
    }
    if (i == n) return true;
    if (out) out->resize(mark);
    return false;
}

inline std::size_t minus(std::size_t a, std::size_t b) { return a > b ? a - b : 0; }
}  // namespace

long Framer::find(std::size_t from, std::size_t to) const {
    to = to < size() ? to : size();
    if (from >= to) return -1;
    const void* p = std::memchr(held(from), START, to - from);
    return p ? static_cast<const std::uint8_t*>(p) - held() : -1;
}

bool Framer::parses(std::size_t from, std::size_t to) const {
    return parse_fields(held(from), to - from, 0, nullptr);
}

bool Framer::starts_packet(std::size_t i) const {
    if (at(i) != START) return false;
    if (size() > i + 3 && at(i + 3) > MAX_DATA) return false;
    if (size() > i + HEADER && at(i + 3) > 0) return field_bytes(at(i + HEADER) & 0xF0) != 0;
    return true;
}

int Framer::packet_at(std::size_t i) const {
    if (!starts_packet(i)) return 0;
    if (size() < i + HEADER) return -1;
    const std::size_t stop = i + HEADER + at(i + 3);
    if (size() < stop) return -1;
    return parses(i + HEADER, stop) ? 1 : 0;
}

int Framer::start_inside(std::size_t end) const {
    for (long i = find(1, end); i >= 0; i = find(static_cast<std::size_t>(i) + 1, end)) {
        const std::size_t k = static_cast<std::size_t>(i);
        if (size() < k + HEADER) return -1;
        if (at(k + 3) > 0 && starts_packet(k)) {
            const std::size_t stop = k + HEADER + at(k + 3);
            if (size() < stop) return -1;
            if (parses(k + HEADER, stop)) return 1;
        }
    }
    return 0;
}

bool Framer::holds_packets(std::size_t end) const {
    for (long i = find(HEADER, end); i >= 0; i = find(static_cast<std::size_t>(i) + 1, end)) {
        std::size_t j = static_cast<std::size_t>(i);
        while (j + HEADER <= end && at(j) == START && at(j + 3) <= MAX_DATA) {
            const std::size_t k = j + HEADER + at(j + 3);
            if (k > end || !parses(j + HEADER, k)) break;
            j = k;
        }
        if (j == end) return true;
    }
    return false;
}

void Framer::reset() {
    clear_held();
    have_stamp_ = false;
}

void Framer::stamp(Wide value, std::size_t width) {
    // a uint16 ms timestamp wraps every 65.536 s: unwrapped against the last one
    if (width != 2 || !have_stamp_) {
        stamp_ms_ = value;
        have_stamp_ = true;
        return;
    }
    const Wide last = stamp_ms_;
    Wide next = last - (last & 0xFFFF) + value;
    if (next < last) next += 0x10000;
    stamp_ms_ = next;
}

void Framer::deliver(const std::vector<Field>& fields, const std::uint8_t* data,
                     double host_time, std::vector<Frame>& out,
                     std::vector<std::uint16_t>& counts) {
    ++packets_;
    const std::uint8_t* array = nullptr;
    for (const Field& f : fields) {
        if (f.finger != finger_) continue;
        const std::uint8_t* p = data + f.at;
        if (f.kind == STATIC) {
            array = p;
        } else if (f.kind == TIMESTAMP) {
            Wide value = 0;
            for (std::size_t b = 0; b < f.size; ++b) value = (value << 8) | p[b];
            stamp(value, f.size);
        } else {
            const Kind k = extra_of(f.kind);
            bool seen = false;
            for (std::uint8_t s = 0; s < extras_.seen; ++s) seen = seen || extras_.order[s] == k;
            if (!seen) extras_.order[extras_.seen++] = k;
            for (std::size_t v = 0; v < f.size / 2; ++v)
                extras_.value[k][v] = static_cast<std::int16_t>((p[2 * v] << 8) | p[2 * v + 1]);
        }
    }
    if (array == nullptr) return;
    Frame frame{seq_++, have_stamp_, 0, stamp_ms_, extras_, counts.size()};
    frame.time_us = have_stamp_ ? stamp_ms_ * 1000 : static_cast<Wide>(host_clock_us(host_time));
    for (std::size_t c = 0; c < ROWS * COLS; ++c)
        counts.push_back(static_cast<std::uint16_t>((array[2 * c] << 8) | array[2 * c + 1]));
    out.push_back(frame);
    accepted();
}

void Framer::feed(const std::uint8_t* data, std::size_t n, double host_time,
                  std::vector<Frame>& out, std::vector<std::uint16_t>& counts) {
    if (n == 0) return;
    std::size_t carried = size();  // bytes at the front that came in earlier reads
    append(data, n);
    while (true) {
        const long start = find(0, size());
        if (start < 0) {
            drop(size());
            break;
        }
        drop(static_cast<std::size_t>(start));
        carried = minus(carried, static_cast<std::size_t>(start));
        if (size() < HEADER) break;
        const std::size_t length = at(3);
        if (length > MAX_DATA) {
            reject(stats_.length_errors);
            drop(1);
            carried = minus(carried, 1);
            continue;
        }
        const std::size_t end = HEADER + length;
        if (size() < end) break;
        fields_.clear();
        if (!parse_fields(held(HEADER), length, 0, &fields_)) {
            reject(stats_.parse_errors);
            drop(1);
            carried = minus(carried, 1);
            continue;
        }
        if (size() == end && carried > 0) break;  // spans reads: the next byte must confirm it
        // what follows: a start whose packet has not all arrived confirms it; a start whose
        // whole packet does not parse is garbage
        const bool follows = size() > end ? packet_at(end) != 0 : true;
        const int inside = follows ? 0 : start_inside(end);
        if (inside < 0) break;  // a packet may start inside it: wait for its bytes to tell
        if (inside > 0 || holds_packets(end)) {
            reject(stats_.truncated);  // a torn packet run into the next one(s)
            drop(1);
            carried = minus(carried, 1);
            continue;
        }
        deliver(fields_, held(HEADER), host_time, out, counts);
        consume(end);
        carried = minus(carried, end);
    }
    compact();
}

}  // namespace robotiq

namespace {
// A Python int of any unsigned 128-bit value (a timestamp's us past 2^64 stays exact).
py::object wide_int(robotiq::Wide v) {
    if (v <= std::numeric_limits<std::uint64_t>::max()) return py::int_(static_cast<std::uint64_t>(v));
    py::int_ hi(static_cast<std::uint64_t>(v >> 64)), lo(static_cast<std::uint64_t>(v));
    return hi.attr("__lshift__")(64).attr("__or__")(lo);
}

// The reference's extras dict: each kind seen (int, or a tuple of 3 ints), then the timestamp.
py::dict extras_dict(const robotiq::Frame& f) {
    static const char* const names[robotiq::KINDS] = {"dynamic", "accelerometer", "gyroscope",
                                                      "magnetometer", "temperature"};
    py::dict extras;
    for (std::uint8_t s = 0; s < f.extras.seen; ++s) {
        const std::uint8_t k = f.extras.order[s];
        const std::int16_t* v = f.extras.value[k];
        if (k == robotiq::DYNAMIC || k == robotiq::TEMPERATURE)
            extras[names[k]] = py::int_(v[0]);
        else
            extras[names[k]] = py::make_tuple(py::int_(v[0]), py::int_(v[1]), py::int_(v[2]));
    }
    if (f.clocked) extras["timestamp"] = wide_int(f.stamp_ms);
    return extras;
}

// The framer as Python sees it: feed(bytes, host_time) -> (seq, device_time_us, raw (7, 4),
// clocked, extras) tuples; the vendor framers' reset, buffered and counters.
class Robotiq {
public:
    explicit Robotiq(unsigned finger) : framer_(finger) {}

    py::list feed(const py::buffer& data, double host_time) {
        const auto bytes = binding::bytes_of(data);
        frames_.clear();
        counts_.clear();
        framer_.feed(bytes.first, bytes.second, host_time, frames_, counts_);
        py::list batch;
        for (const auto& f : frames_)
            batch.append(py::make_tuple(
                f.seq, wide_int(f.time_us),
                binding::counts_array(counts_.data() + f.offset, robotiq::ROWS, robotiq::COLS),
                f.clocked, extras_dict(f)));
        return batch;
    }
    void reset() { framer_.reset(); }
    std::size_t buffered() const { return framer_.buffered(); }
    std::vector<std::uint64_t> counters() const { return binding::counters_of(framer_.stats()); }
    std::uint64_t packets() const { return framer_.packets(); }

private:
    robotiq::Framer framer_;
    std::vector<robotiq::Frame> frames_;
    std::vector<std::uint16_t> counts_;
};
}  // namespace

void bind_robotiq(py::module_& m) {
    py::class_<Robotiq>(m, "RobotiqFramer",
                        "Robotiq TSF-85 packets -> one finger's frames "
                        "(tactiled_drivers.robotiq's core).")
        .def(py::init([](unsigned finger) {
                 if (finger > 3) throw py::value_error("finger: need 0..3");
                 return Robotiq(finger);
             }),
             py::arg("finger"))
        .def("feed", &Robotiq::feed, py::arg("data"), py::arg("host_time"),
             "The frames `data` completes: (seq, device_time_us, raw (7, 4), clocked, extras).")
        .def("reset", &Robotiq::reset)
        .def_property_readonly("buffered", &Robotiq::buffered)
        .def_property_readonly("packets", &Robotiq::packets)
        .def("counters", &Robotiq::counters, "FramerStats' counters, in its field order.");
}
}  // namespace tactiled
