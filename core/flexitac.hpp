// FlexiTac mats: the marker 0xAA 0x55, then rows * cols uint8 readings; no length, seq, clock
// or checksum.  Python reference: drivers/tactiled_drivers/flexitac.py (FlexiTacFramer, whose
// docstring says how a frame's phase is found); tests/drivers/test_vendor_framers.py runs its
// FlexiTac tests against both and holds them equal.  Pure: no I/O, never throws on any bytes.
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

#include "lines.hpp"  // (the vendor framers' bookkeeping: lines::HeldBytes)

namespace tactiled {
namespace flexitac {

struct Frame {
    std::uint32_t seq;
    std::int64_t device_time_us;
    std::size_t offset;  // into the batch's counts
};

class Framer : public lines::HeldBytes {
public:
    Framer(std::size_t rows, std::size_t cols) : cells_(rows * cols), period_(2 + rows * cols) {}
    void feed(const std::uint8_t* data, std::size_t n, double host_time, std::vector<Frame>& out,
              std::vector<std::uint16_t>& counts);
    void reset();
    std::size_t buffered() const { return size(); }

private:
    // where the marker starts in [from, to) of the held bytes (whole marker inside), or -1
    long find(std::size_t from, std::size_t to) const;
    bool find_phase();
    // 0xAA at i followed by a whole marker: a marker torn after its first byte
    bool torn_marker(std::size_t i) const;
    // deliver the frame that starts the held bytes and step over it
    void emit(double host_time, std::vector<Frame>& out, std::vector<std::uint16_t>& counts);
    bool marker_at(std::size_t k) const { return k + 2 <= size() && at(k) == 0xAA && at(k + 1) == 0x55; }

    std::size_t cells_, period_;
    bool synced_ = false;
    std::uint32_t seq_ = 0;
};

}  // namespace flexitac
}  // namespace tactiled
