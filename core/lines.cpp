// The lines framer (core/lines.hpp) and its bindings.
#include "lines.hpp"

#include <cmath>
#include <cstring>
#include <limits>
#include <tuple>

#include "framer_binding.hpp"
#include "stages.hpp"

namespace py = pybind11;

namespace tactiled {
namespace lines {
namespace {
// Python's bytes whitespace (bytes.strip, bytes.split, int)
inline bool space(std::uint8_t c) { return c == ' ' || (c >= '\t' && c <= '\r'); }

enum class Parsed { ok, invalid, overflow };

// int(field, 10) as Python reads it: blanks either side, a sign, digits with single
// underscores between them; `overflow`: a valid integer outside int64.
Parsed parse_int(const std::uint8_t* p, const std::uint8_t* end, std::int64_t& value) {
    while (p < end && space(*p)) ++p;
    while (end > p && space(end[-1])) --end;
    bool negative = false;
    if (p < end && (*p == '+' || *p == '-')) negative = *p++ == '-';
    if (p == end || !(*p >= '0' && *p <= '9')) return Parsed::invalid;
    // accumulate the magnitude negatively: -2^63 fits, 2^63 does not
    std::int64_t acc = 0;
    bool overflow = false;
    std::size_t digits = 0;
    bool after_underscore = false;
    for (; p < end; ++p) {
        const std::uint8_t c = *p;
        if (c == '_') {
            if (after_underscore) return Parsed::invalid;
            after_underscore = true;
            continue;
        }
        if (!(c >= '0' && c <= '9')) return Parsed::invalid;
        after_underscore = false;
        ++digits;
        const int d = c - '0';
        if (!overflow) {
            if (acc < (std::numeric_limits<std::int64_t>::min() + d) / 10)
                overflow = true;
            else
                acc = acc * 10 - d;
        }
    }
    if (after_underscore || digits > MAX_DIGITS) return Parsed::invalid;
    if (overflow) return Parsed::overflow;
    if (!negative) {
        if (acc == std::numeric_limits<std::int64_t>::min()) return Parsed::overflow;
        acc = -acc;
    }
    value = acc;
    return Parsed::ok;
}
}  // namespace

Framer::Framer(std::size_t rows, std::size_t cols, Sep sep, bool time_col, std::int64_t time_scale)
    : cells_(rows * cols), sep_(sep), time_col_(time_col), time_scale_(time_scale) {}

void Framer::reset() {
    cut(buf_.size());
    buf_.clear();
    skipping_ = false;
}

void Framer::check_bound() {
    if (buf_.size() > MAX_LINE) {
        buf_.clear();
        skipping_ = true;
        reject(stats_.oversize);
    }
}

void Framer::line(const std::uint8_t* p, std::size_t n, double host_time, std::vector<Line>& out,
                  std::vector<std::int64_t>& values) {
    if (n > MAX_LINE) {
        reject(stats_.oversize);
        return;
    }
    const std::uint8_t* end = p + n;
    while (p < end && space(*p)) ++p;  // bytes.strip()
    while (end > p && space(end[-1])) --end;
    if (p == end) return;  // a blank line
    const std::uint8_t sep = sep_ == Sep::comma ? ',' : '\t';
    if (sep_ != Sep::space && end[-1] == sep) --end;  // "1,2,3," as print loops leave it
    // the fields: split on the separator, or on runs of blanks
    std::vector<std::pair<const std::uint8_t*, const std::uint8_t*>> fields;
    fields.reserve(cells_ + 1);
    if (sep_ == Sep::space) {
        const std::uint8_t* q = p;
        while (q < end) {
            while (q < end && space(*q)) ++q;
            if (q == end) break;
            const std::uint8_t* a = q;
            while (q < end && !space(*q)) ++q;
            fields.emplace_back(a, q);
        }
    } else {
        const std::uint8_t* a = p;
        for (const std::uint8_t* q = p; q <= end; ++q) {
            if (q == end || *q == sep) {
                fields.emplace_back(a, q);
                a = q + 1;
            }
        }
    }
    const std::size_t want = cells_ + (time_col_ ? 1 : 0);
    if (fields.size() != want) {
        reject(fields.size() < want ? stats_.truncated : stats_.length_errors);
        return;
    }
    const std::size_t mark = values.size();
    values.resize(mark + cells_);
    bool overflow = false;
    std::int64_t stamp = 0;
    bool stamp_bad = false;
    for (std::size_t k = 0; k < want; ++k) {
        std::int64_t v = 0;
        const Parsed r = parse_int(fields[k].first, fields[k].second, v);
        if (r == Parsed::invalid) {
            values.resize(mark);
            reject(stats_.parse_errors);
            return;
        }
        if (time_col_ && k == 0) {
            // the clock: never negative, and within int64 once in microseconds
            if (r == Parsed::overflow || v < 0 ||
                (v > 0 && v > std::numeric_limits<std::int64_t>::max() / time_scale_))
                stamp_bad = true;
            else
                stamp = v * time_scale_;
            continue;
        }
        if (r == Parsed::overflow) overflow = true;
        values[mark + k - (time_col_ ? 1 : 0)] = v;
    }
    if (time_col_) {
        if (stamp_bad) {
            values.resize(mark);
            reject(stats_.parse_errors);
            return;
        }
    } else {
        stamp = host_clock_us(host_time);
    }
    if (overflow) {  // a count beyond int64
        values.resize(mark);
        reject(stats_.parse_errors);
        return;
    }
    const std::uint32_t seq = seq_++;
    out.push_back({seq, stamp, mark});
    accepted();
}

void Framer::feed(const std::uint8_t* data, std::size_t n, double host_time,
                  std::vector<Line>& out, std::vector<std::int64_t>& values) {
    if (n == 0) return;
    stats_.bytes += n;
    const std::uint8_t* end = data + n;
    if (skipping_) {
        const auto* nl = static_cast<const std::uint8_t*>(std::memchr(data, '\n', n));
        if (nl == nullptr) return;
        data = nl + 1;
        skipping_ = false;
    }
    const auto* nl = static_cast<const std::uint8_t*>(
        data < end ? std::memchr(data, '\n', static_cast<std::size_t>(end - data)) : nullptr);
    if (nl == nullptr) {
        buf_.insert(buf_.end(), data, end);
        check_bound();
        return;
    }
    if (buf_.empty()) {
        line(data, static_cast<std::size_t>(nl - data), host_time, out, values);
    } else {
        buf_.insert(buf_.end(), data, nl);
        std::vector<std::uint8_t> first;
        first.swap(buf_);
        line(first.data(), first.size(), host_time, out, values);
    }
    const std::uint8_t* start = nl + 1;
    while (true) {
        const auto* next = static_cast<const std::uint8_t*>(
            start < end ? std::memchr(start, '\n', static_cast<std::size_t>(end - start))
                        : nullptr);
        if (next == nullptr) break;
        line(start, static_cast<std::size_t>(next - start), host_time, out, values);
        start = next + 1;
    }
    buf_.assign(start, end);
    check_bound();
}

}  // namespace lines

void bind_lines(py::module_& m) {
    using Bound = binding::Vendor<lines::Framer, lines::Line, std::int64_t>;
    Bound::bind(m, "LinesFramer", "Text lines of integers -> frames (tactiled_drivers.lines' core).")
        .def(py::init([](std::size_t rows, std::size_t cols, const std::string& sep,
                         bool time_col, std::int64_t time_scale) {
                 if (!(rows >= 1 && cols >= 1 && rows * cols <= lines::MAX_CELLS))
                     throw py::value_error("rows * cols: need 1.." +
                                           std::to_string(lines::MAX_CELLS));
                 if (sep != "," && sep != "\t" && sep != " ")
                     throw py::value_error("sep: ',', '\\t' or ' ' (runs of blanks)");
                 if (time_scale < 1) throw py::value_error("time_scale: a positive number of us");
                 const lines::Sep kind = sep == "," ? lines::Sep::comma
                                         : sep == "\t" ? lines::Sep::tab : lines::Sep::space;
                 return Bound(rows, cols, lines::Framer(rows, cols, kind, time_col, time_scale));
             }),
             py::arg("rows"), py::arg("cols"), py::arg("sep"), py::arg("time_col"),
             py::arg("time_scale"));
}
}  // namespace tactiled
