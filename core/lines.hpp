// Text lines of integers, one frame per line (the `lines://` driver).  Python reference:
// drivers/tactiled_drivers/lines.py (LinesFramer); tests/drivers/test_lines_core.py holds the
// two equal.  Pure: no I/O, never throws on any input bytes, holds at most MAX_LINE bytes.
#pragma once

#include <cmath>
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

namespace tactiled {
namespace lines {

constexpr std::size_t MAX_CELLS = 4096;
constexpr std::size_t MAX_LINE = 21 * (MAX_CELLS + 1);
// Python's int() refuses a decimal of more digits than this (sys.get_int_max_str_digits())
constexpr std::size_t MAX_DIGITS = 4300;

enum class Sep { comma, space, tab };

// FramerStats' counters, in its field order (tactiled_drivers.plumbing.framing.FramerStats)
struct Stats {
    std::uint64_t frames = 0, bytes = 0, resyncs = 0, discarded = 0, truncated = 0,
                  length_errors = 0, oversize = 0, crc_errors = 0, parse_errors = 0,
                  ambiguous = 0, lost = 0, duplicated = 0, restarts = 0;
};

// What the vendor framers share (tactiled_drivers.plumbing.framing.FramerBase): the counters,
// the flag that makes the next good unit a resync, and the host clock of formats that send none.
class FramerBase {
public:
    const Stats& stats() const { return stats_; }

protected:
    void reject(std::uint64_t& counter) { ++counter; in_error_ = true; }
    // bytes skipped looking for a unit's start
    void discard(std::size_t n) {
        if (n > 0) {
            stats_.discarded += n;
            in_error_ = true;
        }
    }
    // reset: the `held` bytes of a unit the unplug cut are one truncated unit
    void cut(std::size_t held) {
        if (held > 0) {
            ++stats_.truncated;
            stats_.discarded += held;
        }
        in_error_ = false;
    }
    // a unit about to be delivered
    void accepted() {
        ++stats_.frames;
        if (in_error_) {
            ++stats_.resyncs;
            in_error_ = false;
        }
    }
    // us of host receive time since the first frame, rounded half to even as Python's round()
    std::int64_t host_clock_us(double host_time) {
        if (!have_t0_) {
            have_t0_ = true;
            t0_ = host_time;
        }
        const double us = std::nearbyint((host_time - t0_) * 1e6);
        return us > 0.0 ? static_cast<std::int64_t>(us) : 0;
    }

    Stats stats_;
    bool in_error_ = false;

private:
    bool have_t0_ = false;
    double t0_ = 0.0;
};

// The bytes a packet framer holds between reads (the Robotiq and FlexiTac framers): a read's
// bytes are appended at the back and consumed from the front by moving a head, so a read of
// many units moves the held bytes once, when the read is done (compact()).
class HeldBytes : public FramerBase {
protected:
    std::size_t size() const { return buf_.size() - head_; }
    std::uint8_t at(std::size_t k) const { return buf_[head_ + k]; }
    const std::uint8_t* held(std::size_t k = 0) const { return buf_.data() + head_ + k; }
    void append(const std::uint8_t* data, std::size_t n) {
        stats_.bytes += n;
        buf_.insert(buf_.end(), data, data + n);
    }
    void consume(std::size_t n) { head_ += n; }  // a unit delivered
    void drop(std::size_t n) {                   // bytes skipped, counted
        head_ += n;
        discard(n);
    }
    void compact() {
        buf_.erase(buf_.begin(), buf_.begin() + static_cast<std::ptrdiff_t>(head_));
        head_ = 0;
    }
    void clear_held() {  // a reset: what was held is one truncated unit
        cut(size());
        buf_.clear();
        head_ = 0;
    }

private:
    std::vector<std::uint8_t> buf_;
    std::size_t head_ = 0;  // bytes of buf_ already consumed
};

struct Line {
    std::uint32_t seq;
    std::int64_t device_time_us;
    std::size_t offset;  // into the batch's values (rows * cols of them)
};

class Framer : public FramerBase {
public:
    Framer(std::size_t rows, std::size_t cols, Sep sep, bool time_col, std::int64_t time_scale);
    void feed(const std::uint8_t* data, std::size_t n, double host_time, std::vector<Line>& out,
              std::vector<std::int64_t>& values);
    void reset();
    std::size_t buffered() const { return buf_.size(); }

private:
    void line(const std::uint8_t* p, std::size_t n, double host_time, std::vector<Line>& out,
              std::vector<std::int64_t>& values);
    void check_bound();

    std::size_t cells_;
    Sep sep_;
    bool time_col_;
    std::int64_t time_scale_;
    std::vector<std::uint8_t> buf_;
    bool skipping_ = false;
    std::uint32_t seq_ = 0;
};

}  // namespace lines
}  // namespace tactiled
