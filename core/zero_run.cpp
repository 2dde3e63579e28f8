// A run of frames through the calibration stage in one call (ZeroRun.run): for each frame,
// what CalibrationStage.process does on its compiled path (zero_frame, the detector's decision
// with its hysteresis and averaging, the zeroer's settling and the baseline's step), so a
// read's frames cost one call into the core, not a dozen Python calls each; the stage's arrays
// are checked once, when it is built.  Python reference: tactiled/calibration/
// fused_reference.py's ZeroRun and zero_run (same arguments, same bits:
// tests/native/test_zero_run.py); RUN_STATE and RUN_CONSTANTS there name the two vectors.
#include "zero_run.hpp"

#include <cmath>
#include <cstdint>
#include <vector>

#include "calibrate_binding.hpp"
#include "stages.hpp"

namespace tactiled {

ZeroRun::ZeroRun(In<double> offset, In<double> breaks, In<std::int64_t> first, In<double> params,
                 py::array baseline, py::array peak, In<double> ax, In<double> ay_t,
                 In<std::int64_t> bands, py::array ring, py::array total, py::array residual,
                 In<double> constants)
    : keep_{offset, breaks, first, params, baseline, peak, ax, ay_t, bands, ring, total,
            residual, constants} {
    n_ = baseline.size();
    seg_ = calib::segments_of(offset, breaks, first, params, n_);
    f_ = calib::filter_of(ax, ay_t, bands, n_);
    base_ = data_of<double>(baseline, "baseline", true, n_);
    pk_ = data_of<double>(peak, "peak", true, n_);
    res_ = data_of<double>(residual, "residual", true, n_);
    const double* c = data_of<double>(constants, "constants", false, ZERO_CONSTANT_SIZE);
    for (py::ssize_t i = 0; i < ZERO_CONSTANT_SIZE; ++i) c_[i] = c[i];
    average_ = static_cast<std::int64_t>(c_[11]);
    p_ = f_.nu * f_.nv;
    if (average_ < 1) throw py::value_error("average: at least 1");
    if (ring.ndim() != 2 || ring.shape(0) != average_ || ring.shape(1) != p_)
        throw py::value_error("ring: shape (average, P)");
    rg_ = data_of<double>(ring, "ring", true);
    tot_ = data_of<double>(total, "total", true, p_);
    tmap_.resize(static_cast<std::size_t>(p_));
    scratch_.resize(static_cast<std::size_t>(n_));
    m_.resize(static_cast<std::size_t>(f_.nu * f_.cols));
}

ZeroState ZeroRun::load(py::array state) const {
    const double* s = data_of<double>(state, "state", true, ZERO_STATE_SIZE);
    ZeroState st;
    st.last_t = s[0];
    st.frames = static_cast<std::int64_t>(s[1]);
    st.settle_until = s[2];
    st.release_until = s[3];
    st.baseline_var = s[4];
    st.in_contact = s[5] != 0.0;
    st.active = s[6] != 0.0;
    st.count = static_cast<std::int64_t>(s[7]);
    st.head = static_cast<std::int64_t>(s[8]);
    if (st.count < 0 || st.count > average_ || st.head < 0 || st.head >= average_)
        throw py::value_error("state: the detector's count or head out of range");
    st.last_statistic = s[9];
    st.det_in = s[10] != 0.0;
    st.residual_valid = s[11] != 0.0;
    st.top = s[12];
    st.released = s[13] != 0.0;
    return st;
}

void ZeroRun::store(const ZeroState& st, py::array state) const {
    double* s = data_of<double>(state, "state", true, ZERO_STATE_SIZE);
    s[0] = st.last_t;
    s[1] = static_cast<double>(st.frames);
    s[3] = st.release_until;
    s[4] = st.baseline_var;
    s[5] = st.in_contact ? 1.0 : 0.0;
    s[6] = st.active ? 1.0 : 0.0;
    s[7] = static_cast<double>(st.count);
    s[8] = static_cast<double>(st.head);
    s[9] = st.last_statistic;
    s[10] = st.det_in ? 1.0 : 0.0;
    s[11] = st.residual_valid ? 1.0 : 0.0;
    s[12] = st.top;
    s[13] = st.released ? 1.0 : 0.0;
}

ZeroStep ZeroRun::frame(const py::handle& raw_obj, double t, double* zi, ZeroState& s,
                        double& stat_out, double& peak_out) {
    const py::ssize_t n = n_;
    const double fraction = c_[0], tau_s = c_[1], floor = c_[2], margin = c_[3], sigma = c_[4];
    const double enter = c_[5], exit_ = c_[6], tau_drift = c_[7], tau_release = c_[8];
    const double holdoff = c_[9], max_step = c_[10];
    if (!py::isinstance<py::array>(raw_obj)) throw py::type_error("raws: numpy arrays");
    py::array raw = py::reinterpret_borrow<py::array>(raw_obj);
    if (raw.size() != n) throw py::value_error("raws: a frame of another size");
    const double dt = t - s.last_t;
    double* ri = fraction > 0.0 ? scratch_.data() : zi;
    const double decay = dt > 0.0 ? std::exp(-dt / tau_s) : 1.0;
    calib::ZeroResult r{};
    const auto zero = [&](auto* rp) {
        r = calib::zero_frame(rp, n, seg_, base_, pk_, fraction, decay, floor, margin, s.active,
                              f_, zi, ri, tmap_.data(), m_.data());
    };
    if (py::isinstance<py::array_t<std::uint16_t>>(raw) && (raw.flags() & py::array::c_style)) {
        zero(static_cast<const std::uint16_t*>(raw.data()));
    } else if (py::isinstance<py::array_t<std::int64_t>>(raw) &&
               (raw.flags() & py::array::c_style)) {
        zero(static_cast<const std::int64_t*>(raw.data()));
    } else {  // any other counts: as float64, as zero_frame takes them
        auto d = py::array_t<double, py::array::c_style | py::array::forcecast>::ensure(raw);
        if (!d) throw py::type_error("raws: expected numeric counts");
        as_double_.assign(d.data(), d.data() + n);
        zero(as_double_.data());
    }
    if (r.state < 0) return ZERO_NOT_TAKEN;  // a value the table cannot take: the reference's
    s.top = r.peak;
    ++s.frames;
    const bool settling = t < s.settle_until;
    s.last_t = t;
    s.residual_valid = (r.state & 1) != 0;
    if (s.residual_valid)
        for (py::ssize_t k = 0; k < n; ++k) res_[k] = scratch_[k];
    if (fraction > 0.0) s.active = (r.state & 2) != 0;
    bool contact = false;
    if (!settling) {
        double stat = r.statistic;
        if (average_ > 1)
            stat = calib::average_maps(rg_, tot_, tmap_.data(), average_, p_, s.count, s.head);
        s.last_statistic = stat;
        s.det_in = s.det_in ? stat >= exit_ : stat > enter;
        contact = s.det_in;
    }
    stat_out = s.last_statistic;
    peak_out = r.peak;
    if (contact) {
        s.in_contact = true;
        return ZERO_CONTACT;
    }
    if (s.in_contact) {
        s.in_contact = false;
        s.release_until = t + holdoff;
        s.released = true;
    }
    if (dt > 0.0) {
        const double tau = t < s.release_until ? tau_release : tau_drift;
        const double ema = -std::expm1(-dt / tau);
        const double mean = 1.0 / static_cast<double>(s.frames);
        const double sigma2 = std::pow(sigma, 2.0);
        if (mean >= ema) {
            calib::follow_baseline(base_, zi, n, mean, 0.0, false);
            s.baseline_var = sigma2 * mean;
        } else {
            s.baseline_var = std::pow(1.0 - ema, 2.0) * s.baseline_var + ema * ema * sigma2;
            calib::follow_baseline(base_, zi, n, ema, max_step, true);
        }
    }
    return ZERO_QUIET;
}

void check_one_per_frame(py::ssize_t frames, py::ssize_t n, const py::array& z,
                         const py::array& times, const py::array& stats, const py::array& peaks) {
    if (z.size() < frames * n || times.size() < frames || stats.size() < frames ||
        peaks.size() < frames)
        throw py::value_error("z, times, stats, peaks: one per frame");
}

std::int64_t ZeroRun::run(py::list raws, py::array times, py::array z, py::array stats,
                          py::array peaks, py::array state) {
    const py::ssize_t count_frames = static_cast<py::ssize_t>(raws.size());
    double* zz = data_of<double>(z, "z", true);
    const double* tm = data_of<double>(times, "times", false);
    double* st = data_of<double>(stats, "stats", true);
    double* pks = data_of<double>(peaks, "peaks", true);
    check_one_per_frame(count_frames, n_, z, times, stats, peaks);
    ZeroState s = load(state);
    std::int64_t taken = 0;
    for (py::ssize_t i = 0; i < count_frames; ++i) {
        const ZeroStep step = frame(raws[i], tm[i], zz + i * n_, s, st[i], pks[i]);
        if (step == ZERO_NOT_TAKEN) break;
        ++taken;
        if (step == ZERO_CONTACT) break;
    }
    store(s, state);
    return taken;
}

void bind_zero_run(py::module_& m) {
    py::class_<ZeroRun>(m, "ZeroRun",
                        "A stage's runs of frames through the calibration stage, until the first "
                        "in contact (tactiled.calibration.fused_reference.ZeroRun).")
        .def(py::init<In<double>, In<double>, In<std::int64_t>, In<double>, py::array,
                      py::array, In<double>, In<double>, In<std::int64_t>, py::array,
                      py::array, py::array, In<double>>(),
             py::arg("offset"), py::arg("breaks"), py::arg("first"), py::arg("params"),
             py::arg("baseline"), py::arg("peak"), py::arg("ax"), py::arg("ay_t"),
             py::arg("bands"), py::arg("ring"), py::arg("total"), py::arg("residual"),
             py::arg("constants"))
        .def("run", &ZeroRun::run, py::arg("raws"), py::arg("times"), py::arg("z"),
             py::arg("stats"), py::arg("peaks"), py::arg("state"));
}
}  // namespace tactiled
