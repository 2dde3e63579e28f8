// The tactiled wire format's stream decoder (docs/reference/protocol.md): COBS-framed
// header | uint16 LE counts | CRC-32, 0x00-delimited.  Python reference: tactiled/frames.py
// (FrameDecoder, _parse, _cobs_decode); every branch here mirrors one there, and the tests
// (tests/reliability/test_decoder_fuzz.py, tests/native/fuzz_framers.py) hold the two equal
// on hostile and hypothesis-drawn streams.
// Pure: no I/O, never throws on any input bytes, holds at most MAX_ENCODED_LEN bytes.
#pragma once

#include <cstddef>
#include <cstdint>
#include <unordered_map>
#include <vector>

namespace tactiled {
namespace wire {

constexpr int VERSION = 1;       // a 1-axis frame: one count per tactel
constexpr int VERSION_AXES = 2;  // byte 1 is `axes`, the readings per taxel (1 or 3)
// <BBHIQBB: version, flags (version 2: axes), sensor_id, seq, t_us, rows, cols
constexpr std::size_t HEADER_LEN = 18;
constexpr std::size_t CRC_LEN = 4;
constexpr std::size_t MAX_TACTELS = 4096;  // counts per frame: rows * cols * axes
constexpr std::size_t MAX_DECODED_LEN = HEADER_LEN + 2 * MAX_TACTELS + CRC_LEN;
constexpr std::size_t MAX_ENCODED_LEN = MAX_DECODED_LEN + (MAX_DECODED_LEN + 253) / 254;

// zlib.crc32 (IEEE 802.3, reflected polynomial 0xEDB88320)
std::uint32_t crc32(const std::uint8_t* data, std::size_t n);

// DecoderStats' counters, in its field order (tactiled.frames.DecoderStats)
struct Stats {
    std::uint64_t frames = 0, bytes = 0, crc_errors = 0, length_errors = 0, version_errors = 0,
                  cobs_errors = 0, truncated = 0, oversize = 0, lost = 0, duplicated = 0,
                  restarts = 0, resyncs = 0;
};

// One decoded frame: counts row-major (rows * cols * axes values, x y z per taxel) in
// `counts`, at `offset`.
struct Decoded {
    std::uint32_t seq;
    std::uint64_t device_time_us;
    std::uint16_t sensor_id;
    std::uint8_t rows, cols, axes;
    std::size_t offset;  // into the batch's counts
};

// Where a chunk went: a frame, or the counter it was rejected in.
enum class Verdict { frame, crc_errors, length_errors, version_errors, cobs_errors, truncated };

class Decoder {
public:
    // Consume `n` bytes; the frames they complete are appended to `out` (their counts to
    // `counts`), in stream order.
    void feed(const std::uint8_t* data, std::size_t n, std::vector<Decoded>& out,
              std::vector<std::uint16_t>& counts);
    void reset();
    std::size_t buffered() const { return buf_.size(); }
    const Stats& stats() const { return stats_; }

private:
    void chunk(const std::uint8_t* data, std::size_t n, std::vector<Decoded>& out,
               std::vector<std::uint16_t>& counts);
    void check_bound();
    void reject(std::uint64_t& counter) { ++counter; in_error_ = true; }
    bool accept(const Decoded& f);

    Stats stats_;
    std::vector<std::uint8_t> buf_;
    std::vector<std::uint8_t> scratch_;
    bool discarding_ = false;
    bool in_error_ = false;
    std::unordered_map<std::uint16_t, std::uint32_t> last_seq_;
};

// One delimiter-free chunk: the verdict and, for a frame, its header and counts (appended).
Verdict parse(const std::uint8_t* chunk, std::size_t n, std::vector<std::uint8_t>& scratch,
              Decoded& frame, std::vector<std::uint16_t>& counts);

}  // namespace wire
}  // namespace tactiled
