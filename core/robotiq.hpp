// Robotiq TSF-85 packets: 0x9A, a CRC byte (not checked: no source computes it), a command
// byte, a data length (<= 60), then fields (a type byte: high nibble the kind, bits 2-3 the
// finger; a big-endian payload).  A frame is one finger's 7x4 static array with its latest
// dynamic, IMU, temperature and (unwrapped) timestamp fields.  Python reference:
// drivers/tactiled_drivers/robotiq.py (RobotiqFramer, whose module text says how a packet is
// accepted, a torn one rejected, and why); tests/drivers/test_vendor_framers.py and
// tests/native/fuzz_framers.py hold the two equal.  Pure: no I/O, never throws on any bytes.
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

#include "lines.hpp"  // (the vendor framers' bookkeeping: lines::FramerBase)

namespace tactiled {
namespace robotiq {

constexpr std::uint8_t START = 0x9A;
constexpr std::size_t HEADER = 4, MAX_DATA = 60, ROWS = 7, COLS = 4;
// Milliseconds and microseconds of the finger's clock: a uint64 timestamp (pyrobotiqtactile's)
// may be any value, so its microseconds (and unwrapping past it) need more than 64 bits, as
// the reference's Python ints have.
using Wide = unsigned __int128;

// The extras a frame carries (the finger's latest of each kind), in the order the reference's
// dict first saw them.
enum Kind : std::uint8_t { DYNAMIC, ACCEL, GYRO, MAGNET, TEMPERATURE, KINDS };
struct Extras {
    std::uint8_t order[KINDS];  // kinds in first-seen order
    std::uint8_t seen = 0;      // how many of `order` are set
    std::int16_t value[KINDS][3] = {};
};

// A field of a packet: its type byte's kind (high nibble) and finger, its payload's place.
struct Field {
    std::uint8_t kind, finger;
    std::size_t at, size;  // payload: offset from the packet's data, bytes
};

struct Frame {
    std::uint32_t seq;
    bool clocked;      // device_time_us is the finger's clock (stamp_ms * 1000)
    Wide time_us;      // device time, us
    Wide stamp_ms;     // the unwrapped timestamp (clocked frames)
    Extras extras;
    std::size_t offset;  // into the batch's counts
};

class Framer : public lines::HeldBytes {
public:
    explicit Framer(unsigned finger) : finger_(finger) {}
    void feed(const std::uint8_t* data, std::size_t n, double host_time, std::vector<Frame>& out,
              std::vector<std::uint16_t>& counts);
    void reset();
    std::size_t buffered() const { return size(); }
    std::uint64_t packets() const { return packets_; }
    unsigned finger() const { return finger_; }

private:
    long find(std::size_t from, std::size_t to) const;  // START in [from, to), or -1
    bool starts_packet(std::size_t i) const;
    int packet_at(std::size_t i) const;       // 1, 0, or -1: its bytes have not all arrived
    int start_inside(std::size_t end) const;  // 1, 0, or -1: as packet_at
    bool holds_packets(std::size_t end) const;
    bool parses(std::size_t from, std::size_t to) const;
    void deliver(const std::vector<Field>& fields, const std::uint8_t* data, double host_time,
                 std::vector<Frame>& out, std::vector<std::uint16_t>& counts);
    void stamp(Wide value, std::size_t width);

    unsigned finger_;
    std::uint32_t seq_ = 0;
    bool have_stamp_ = false;
    Wide stamp_ms_ = 0;
    Extras extras_;
    std::uint64_t packets_ = 0;
    std::vector<Field> fields_;  // the packet being read (kept: no allocation per packet)
};

}  // namespace robotiq
}  // namespace tactiled
