// The calibration kernels (core/calibrate.hpp) and their bindings, argument for argument those
// of tactiled/calibration/fused_reference.py: arrays are written in place, so an output array
// of the wrong dtype or layout is refused (TypeError), never silently copied.
#include "calibrate.hpp"

#include <pybind11/numpy.h>

#include <cmath>
#include <limits>
#include <string>
#include <tuple>
#include <vector>

#include "arrays.hpp"
#include "calibrate_binding.hpp"
#include "stages.hpp"

namespace py = pybind11;

namespace tactiled {
namespace calib {

template <class Raw>
ZeroResult zero_frame(const Raw* raw, std::int64_t n, const Segments& seg, const double* baseline,
                      double* peak, double fraction, double decay, double floor, double margin,
                      bool active, const Filter& f, double* z, double* residual, double* tmap,
                      double* m) {
    const std::int64_t nb = seg.nb;
    const std::int64_t np = seg.np;
    for (std::int64_t t = 0; t < n; ++t) {
        const double x = static_cast<double>(raw[t]);
        const double q = x + seg.offset[t];
        std::int64_t lo = seg.first[t], hi = seg.first[t + 1];
        if (seg.breaks[lo] <= q && (hi == nb || q < seg.breaks[hi])) {
            lo += 1;
        } else {
            lo = 0;
            hi = nb;
        }
        while (lo < hi) {
            const std::int64_t mid = (lo + hi) >> 1;
            if (seg.breaks[mid] <= q)
                lo = mid + 1;
            else
                hi = mid;
        }
        double y = x - seg.params[0 * np + lo];
        y *= seg.params[1 * np + lo];
        y += seg.params[2 * np + lo];
        y = py_min(y, seg.params[3 * np + lo]);
        y = py_max(y, seg.params[4 * np + lo]);
        if (!std::isfinite(y)) return {-1, 0.0, 0.0};
        z[t] = y - baseline[t];
    }
    std::int64_t state = 0;
    if (fraction > 0.0) {
        double zmax = z[0];
        for (std::int64_t t = 0; t < n; ++t) zmax = py_max(zmax, z[t]);
        if (active || zmax >= floor) {
            const double gain = fraction / (1.0 - fraction);
            double top = 0.0;
            for (std::int64_t t = 0; t < n; ++t) {
                double p = peak[t] * decay;
                const double zt = z[t];
                double taken = 0.0;
                if (zt < p && p > floor) taken = py_min((p - zt) * gain, fraction * p);
                residual[t] = taken;
                p = py_max(p, zt - margin);
                peak[t] = p;
                top = py_max(top, p);
                z[t] = zt - taken;
            }
            state = 1 | (top > floor ? 2 : 0);
        }
    }
    const std::int64_t cols = f.cols, nu = f.nu, nv = f.nv, nbd = f.nbands;
    for (std::int64_t k = 0; k < nu * cols; ++k) m[k] = 0.0;
    for (std::int64_t u = 0; u < nu; ++u) {
        for (std::int64_t i = f.bands[0 * nbd + u]; i < f.bands[1 * nbd + u]; ++i) {
            const double a = f.ax[u * f.rows + i];
            for (std::int64_t j = 0; j < cols; ++j) m[u * cols + j] += a * z[i * cols + j];
        }
    }
    double stat = -std::numeric_limits<double>::infinity();
    for (std::int64_t u = 0; u < nu; ++u) {
        for (std::int64_t v = 0; v < nv; ++v) {
            double s = 0.0;
            for (std::int64_t j = f.bands[2 * nbd + v]; j < f.bands[3 * nbd + v]; ++j)
                s += m[u * cols + j] * f.ay_t[j * nv + v];
            tmap[u * nv + v] = s;
            stat = py_max(stat, s);
        }
    }
    double top = z[0];
    for (std::int64_t t = 1; t < n; ++t) top = py_max(top, z[t]);
    return {state, stat, top};
}

void follow_baseline(double* baseline, double* z, std::int64_t n, double weight, double limit,
                     bool clip) {
    if (clip) {
        std::int64_t beyond = 0;
        for (std::int64_t t = 0; t < n; ++t)
            if (std::abs(z[t]) > limit) ++beyond;
        if (beyond * 2 > n) {
            for (std::int64_t t = 0; t < n; ++t) {
                z[t] = py_min(py_max(z[t], -limit), limit);
                baseline[t] += weight * z[t];
            }
            return;
        }
    }
    for (std::int64_t t = 0; t < n; ++t) baseline[t] += weight * z[t];
}

// zero_frame's counts types: the wire's, any integer as int64, anything else as double.
template ZeroResult zero_frame<std::uint16_t>(const std::uint16_t*, std::int64_t, const Segments&,
                                              const double*, double*, double, double, double,
                                              double, bool, const Filter&, double*, double*,
                                              double*, double*);
template ZeroResult zero_frame<std::int64_t>(const std::int64_t*, std::int64_t, const Segments&,
                                             const double*, double*, double, double, double,
                                             double, bool, const Filter&, double*, double*,
                                             double*, double*);
template ZeroResult zero_frame<double>(const double*, std::int64_t, const Segments&,
                                       const double*, double*, double, double, double, double,
                                       bool, const Filter&, double*, double*, double*, double*);

double average_maps(double* rg, double* tot, const double* tm, std::int64_t average,
                    std::int64_t p, std::int64_t& count, std::int64_t& head) {
    if (count == 0) {
        for (std::int64_t i = 0; i < p; ++i) tot[i] = tm[i];
    } else {
        for (std::int64_t i = 0; i < p; ++i) tot[i] += tm[i];
        if (count == average)
            for (std::int64_t i = 0; i < p; ++i) tot[i] -= rg[head * p + i];
    }
    for (std::int64_t i = 0; i < p; ++i) rg[head * p + i] = tm[i];
    head = (head + 1) % average;
    count = count + 1 < average ? count + 1 : average;
    const double factor = count == average ? 1.0 / static_cast<double>(count)
                                           : 1.0 / std::sqrt(static_cast<double>(count * average));
    double stat = -std::numeric_limits<double>::infinity();
    for (std::int64_t i = 0; i < p; ++i) stat = py_max(stat, tot[i] * factor);
    return stat;
}

Segments segments_of(const In<double>& offset, const In<double>& breaks,
                     const In<std::int64_t>& first, const In<double>& params, std::int64_t n) {
    Segments seg{};
    seg.offset = data_of<double>(offset, "offset", false, n);
    seg.breaks = data_of<double>(breaks, "breaks", false);
    seg.nb = breaks.size();
    seg.first = data_of<std::int64_t>(first, "first", false, n + 1);
    if (params.ndim() != 2 || params.shape(0) != 5)
        throw py::value_error("params: expected shape (5, N)");
    seg.params = data_of<double>(params, "params", false);
    seg.np = params.shape(1);
    if (seg.nb == 0) throw py::value_error("breaks: empty");
    // (first indexes the breaks and params: checked once here, not per tactel)
    for (std::int64_t t = 0; t <= n; ++t)
        if (seg.first[t] < 0 || seg.first[t] >= seg.nb + (t == n ? 1 : 0))
            throw py::value_error("first out of range");
    if (seg.np < seg.nb + 1) throw py::value_error("params: need one column per segment");
    return seg;
}

Filter filter_of(const In<double>& ax, const In<double>& ay_t, const In<std::int64_t>& bands,
                 std::int64_t n) {
    if (ax.ndim() != 2 || ay_t.ndim() != 2 || bands.ndim() != 2 || bands.shape(0) != 4)
        throw py::value_error("ax, ay_t: 2-d; bands: (4, N)");
    Filter f{};
    f.ax = data_of<double>(ax, "ax", false);
    f.ay_t = data_of<double>(ay_t, "ay_t", false);
    f.bands = data_of<std::int64_t>(bands, "bands", false);
    f.nu = ax.shape(0);
    f.rows = ax.shape(1);
    f.cols = ay_t.shape(0);
    f.nv = ay_t.shape(1);
    f.nbands = bands.shape(1);
    if (f.rows * f.cols != n || f.nbands < f.nu || f.nbands < f.nv)
        throw py::value_error("filter matrices do not match the frame");
    // (bands index the matrices and the frame: checked once here, not per tactel)
    const std::int64_t* b = f.bands;
    for (std::int64_t u = 0; u < f.nu; ++u)
        if (b[u] < 0 || b[f.nbands + u] > f.rows) throw py::value_error("bands out of range");
    for (std::int64_t v = 0; v < f.nv; ++v)
        if (b[2 * f.nbands + v] < 0 || b[3 * f.nbands + v] > f.cols)
            throw py::value_error("bands out of range");
    return f;
}
}  // namespace calib

namespace {
std::tuple<std::int64_t, double, double> zero_frame_py(
    py::array raw, In<double> offset, In<double> breaks, In<std::int64_t> first,
    In<double> params, In<double> baseline, py::array peak, double fraction, double decay,
    double floor, double margin, bool active, In<double> ax, In<double> ay_t,
    In<std::int64_t> bands, py::array z, py::array residual, py::array tmap) {
    const py::ssize_t n = raw.size();
    if (raw.ndim() != 1) throw py::value_error("raw: expected a flat array");
    const calib::Segments seg = calib::segments_of(offset, breaks, first, params, n);
    const calib::Filter f = calib::filter_of(ax, ay_t, bands, n);
    const double* base = data_of<double>(baseline, "baseline", false, n);
    double* pk = data_of<double>(peak, "peak", true, n);
    double* zz = data_of<double>(z, "z", true, n);
    double* res = data_of<double>(residual, "residual", true, n);
    double* tm = data_of<double>(tmap, "tmap", true, f.nu * f.nv);
    std::vector<double> m(static_cast<std::size_t>(f.nu * f.cols));
    calib::ZeroResult r{};
    const auto run = [&](auto* rp) {
        r = calib::zero_frame(rp, n, seg, base, pk, fraction, decay, floor, margin, active, f, zz,
                              res, tm, m.data());
    };
    if (py::isinstance<py::array_t<std::uint16_t>>(raw) && (raw.flags() & py::array::c_style)) {
        run(static_cast<const std::uint16_t*>(raw.data()));
    } else if (py::isinstance<py::array_t<std::int64_t>>(raw) &&
               (raw.flags() & py::array::c_style)) {
        run(static_cast<const std::int64_t*>(raw.data()));
    } else {  // any other counts: as float64, the value numba's float() gives
        auto d = py::array_t<double, py::array::c_style | py::array::forcecast>::ensure(raw);
        if (!d) throw py::type_error("raw: expected numeric counts");
        run(d.data());
    }
    return {r.state, r.statistic, r.peak};
}

std::tuple<std::int64_t, std::int64_t, double> average_maps_py(py::array ring, py::array total,
                                                               In<double> tmap, std::int64_t count,
                                                               std::int64_t head) {
    if (ring.ndim() != 2) throw py::value_error("ring: expected 2-d");
    const std::int64_t average = ring.shape(0), p = tmap.size();
    if (average < 1 || ring.shape(1) != p) throw py::value_error("ring: shape (average, P)");
    if (head < 0 || head >= average || count < 0 || count > average)
        throw py::value_error("count or head out of range");
    double* rg = data_of<double>(ring, "ring", true);
    double* tot = data_of<double>(total, "total", true, p);
    const double* tm = data_of<double>(tmap, "tmap", false);
    const double stat = calib::average_maps(rg, tot, tm, average, p, count, head);
    return {count, head, stat};
}

void follow_baseline_py(py::array baseline, py::array z, double weight, double limit, bool clip) {
    const py::ssize_t n = z.size();
    calib::follow_baseline(data_of<double>(baseline, "baseline", true, n),
                           data_of<double>(z, "z", true, n), n, weight, limit, clip);
}

std::tuple<std::int64_t, double, bool> drift_error_py(In<double> zeroed, In<double> predicted,
                                                      In<bool> inside, py::array error) {
    const py::ssize_t n = zeroed.size();
    const double* zr = data_of<double>(zeroed, "zeroed", false);
    const double* pr = data_of<double>(predicted, "predicted", false, n);
    const bool* in = data_of<bool>(inside, "inside", false, n);
    double* er = data_of<double>(error, "error", true, n);
    std::int64_t n_in = 0;
    double miss = 0.0;
    bool finite = true;
    for (py::ssize_t t = 0; t < n; ++t) {
        const double e = zr[t] - pr[t];
        er[t] = e;
        if (in[t]) {
            ++n_in;
            miss += e * e;
        }
        if (!std::isfinite(e)) finite = false;
    }
    return {n_in, miss, finite};
}

void pull_baseline_py(py::array baseline, In<double> error, In<bool> inside, double limit,
                      double weight, std::int64_t outside) {
    const py::ssize_t n = error.size();
    double* b = data_of<double>(baseline, "baseline", true, n);
    const double* er = data_of<double>(error, "error", false);
    const bool* in = data_of<bool>(inside, "inside", false, n);
    using calib::py_max;
    using calib::py_min;
    double common = 0.0;
    for (py::ssize_t t = 0; t < n; ++t)
        if (!in[t]) common += py_min(py_max(er[t], -limit), limit) * weight;
    common /= static_cast<double>(outside);
    for (py::ssize_t t = 0; t < n; ++t) {
        if (in[t])
            b[t] += common;
        else
            b[t] += py_min(py_max(er[t], -limit), limit) * weight;
    }
}

bool learn_hysteresis_py(py::array peaks, In<double> taus, double dt, In<double> predicted,
                         In<double> unexplained, In<bool> outside, double floor, py::array normal,
                         py::array moment, double forget) {
    if (peaks.ndim() != 2) throw py::value_error("peaks: expected 2-d");
    const std::int64_t kk = peaks.shape(0), n = peaks.shape(1);
    if (normal.ndim() != 3 || normal.shape(0) != kk || normal.shape(1) != 3 ||
        normal.shape(2) != 3 || moment.ndim() != 2 || moment.shape(0) != kk ||
        moment.shape(1) != 3)
        throw py::value_error("normal: (k, 3, 3), moment: (k, 3)");
    double* pk = data_of<double>(peaks, "peaks", true);
    const double* ta = data_of<double>(taus, "taus", false, kk);
    const double* pr = data_of<double>(predicted, "predicted", false, n);
    const double* un = data_of<double>(unexplained, "unexplained", false, n);
    const bool* out = data_of<bool>(outside, "outside", false, n);
    double* nm = data_of<double>(normal, "normal", true);
    double* mo = data_of<double>(moment, "moment", true);
    using calib::py_max;
    if (dt > 0.0) {
        for (std::int64_t k = 0; k < kk; ++k) {
            const double decay = std::exp(-dt / ta[k]);
            for (std::int64_t j = 0; j < n; ++j) pk[k * n + j] *= decay;
        }
    }
    for (std::int64_t j = 0; j < n; ++j) {
        const double load = py_max(pr[j], 0.0);
        for (std::int64_t k = 0; k < kk; ++k)
            if (load > pk[k * n + j]) pk[k * n + j] = load;
    }
    std::vector<double> qq(kk, 0.0), ql(kk, 0.0), q1(kk, 0.0), qe(kk, 0.0);
    double ll = 0.0, l1 = 0.0, le = 0.0, e1 = 0.0;
    std::int64_t count = 0;
    bool trail = false;
    for (std::int64_t j = 0; j < n; ++j) {
        if (!out[j]) continue;
        const double load = py_max(pr[j], 0.0);
        const double e = un[j];
        ++count;
        ll += load * load;
        l1 += load;
        le += load * e;
        e1 += e;
        for (std::int64_t k = 0; k < kk; ++k) {
            const double held = pk[k * n + j];
            if (held > floor) {
                const double q = held - load;
                if (q != 0.0) trail = true;
                qq[k] += q * q;
                ql[k] += q * load;
                q1[k] += q;
                qe[k] += q * e;
            }
        }
    }
    if (!trail) return false;
    for (std::int64_t k = 0; k < kk; ++k) {
        double* N = nm + 9 * k;
        double* M = mo + 3 * k;
        for (int a = 0; a < 3; ++a) {
            M[a] *= forget;
            for (int b = 0; b < 3; ++b) N[3 * a + b] *= forget;
        }
        N[0] += qq[k];
        N[1] += ql[k];
        N[3] += ql[k];
        N[2] += q1[k];
        N[6] += q1[k];
        N[4] += ll;
        N[5] += l1;
        N[7] += l1;
        N[8] += static_cast<double>(count);
        M[0] += qe[k];
        M[1] += le;
        M[2] += e1;
    }
    return true;
}
}  // namespace

void bind_calibrate(py::module_& m) {
    m.def("zero_frame", &zero_frame_py,
          "One frame through the table, the baseline, the hysteresis compensator and the matched "
          "filter (tactiled.calibration.fused_reference.zero_frame).");
    m.def("average_maps", &average_maps_py,
          "The detector's running mean of its filter maps (fused_reference.average_maps).");
    m.def("follow_baseline", &follow_baseline_py,
          "The baseline's step towards an untouched frame (fused_reference.follow_baseline).");
    m.def("drift_error", &drift_error_py,
          "The drift error under a held contact (fused_reference.drift_error).");
    m.def("pull_baseline", &pull_baseline_py,
          "The baseline's step under a held contact (fused_reference.pull_baseline).");
    m.def("learn_hysteresis", &learn_hysteresis_py,
          "One step of the hysteresis learner (fused_reference.learn_hysteresis).");
}
}  // namespace tactiled
