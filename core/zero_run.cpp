// A run of frames through the calibration stage in one call (ZeroRun.run): for each frame,
// what CalibrationStage.process does on its compiled path (zero_frame, the detector's decision
// with its hysteresis and averaging, the zeroer's settling and the baseline's step), so a
// read's frames cost one call into the core, not a dozen Python calls each; the stage's arrays
// are checked once, when it is built.  Python reference: tactiled/calibration/
// fused_reference.py's ZeroRun and zero_run (same arguments, same bits:
// tests/native/test_zero_run.py); RUN_STATE and RUN_CONSTANTS there name the two vectors.
#include <pybind11/numpy.h>

#include <cmath>
#include <cstdint>
#include <vector>

#include "arrays.hpp"
#include "calibrate.hpp"
#include "calibrate_binding.hpp"
#include "stages.hpp"

namespace py = pybind11;

namespace tactiled {
namespace {

// RUN_STATE's and RUN_CONSTANTS' lengths (fused_reference.py)
constexpr py::ssize_t STATE_SIZE = 14;
constexpr py::ssize_t CONSTANT_SIZE = 12;

// One stage's run: its arrays and constants checked once (the table's segments, the
// baseline and peak-hold, the filter, the detector's ring), then a read's frames a call.
class ZeroRun {
public:
    ZeroRun(In<double> offset, In<double> breaks, In<std::int64_t> first, In<double> params,
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
        const double* c = data_of<double>(constants, "constants", false, CONSTANT_SIZE);
        for (py::ssize_t i = 0; i < CONSTANT_SIZE; ++i) c_[i] = c[i];
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

    std::int64_t run(py::list raws, py::array times, py::array z, py::array stats,
                     py::array peaks, py::array state);

private:
    std::vector<py::object> keep_;  // the arrays the pointers below point into
    py::ssize_t n_ = 0;
    calib::Segments seg_{};
    calib::Filter f_{};
    double *base_ = nullptr, *pk_ = nullptr, *res_ = nullptr, *rg_ = nullptr, *tot_ = nullptr;
    double c_[CONSTANT_SIZE] = {};
    std::int64_t average_ = 1, p_ = 0;
    std::vector<double> tmap_, scratch_, m_, as_double_;
};

std::int64_t ZeroRun::run(py::list raws, py::array times, py::array z, py::array stats,
                          py::array peaks, py::array state) {
    const py::ssize_t count_frames = static_cast<py::ssize_t>(raws.size());
    const py::ssize_t n = n_;
    double* zz = data_of<double>(z, "z", true);
    const double* tm_times = data_of<double>(times, "times", false);
    double* st = data_of<double>(stats, "stats", true);
    double* pks = data_of<double>(peaks, "peaks", true);
    if (z.size() < count_frames * n || times.size() < count_frames ||
        stats.size() < count_frames || peaks.size() < count_frames)
        throw py::value_error("z, times, stats, peaks: one per frame");
    double* s = data_of<double>(state, "state", true, STATE_SIZE);
    const double fraction = c_[0], tau_s = c_[1], floor = c_[2], margin = c_[3], sigma = c_[4];
    const double enter = c_[5], exit_ = c_[6], tau_drift = c_[7], tau_release = c_[8];
    const double holdoff = c_[9], max_step = c_[10];
    const std::int64_t average = average_, p = p_;
    const calib::Segments& seg = seg_;
    const calib::Filter& f = f_;
    double *base = base_, *pk = pk_, *res = res_, *rg = rg_, *tot = tot_;

    double last_t = s[0];
    std::int64_t frames = static_cast<std::int64_t>(s[1]);
    const double settle_until = s[2];
    double release_until = s[3], baseline_var = s[4];
    bool in_contact = s[5] != 0.0, active = s[6] != 0.0;
    std::int64_t count = static_cast<std::int64_t>(s[7]), head = static_cast<std::int64_t>(s[8]);
    if (count < 0 || count > average || head < 0 || head >= average)
        throw py::value_error("state: the detector's count or head out of range");
    double last_statistic = s[9];
    bool det_in = s[10] != 0.0, residual_valid = s[11] != 0.0;
    double top = s[12];
    bool released = s[13] != 0.0;

    std::vector<double>& tmap = tmap_;
    std::vector<double>& scratch = scratch_;
    std::vector<double>& m = m_;
    std::vector<double>& as_double = as_double_;
    std::int64_t taken = 0;
    for (py::ssize_t i = 0; i < count_frames; ++i) {
        if (!py::isinstance<py::array>(raws[i])) throw py::type_error("raws: numpy arrays");
        py::array raw = py::reinterpret_borrow<py::array>(raws[i]);
        if (raw.size() != n) throw py::value_error("raws: a frame of another size");
        const double t = tm_times[i];
        const double dt = t - last_t;
        double* zi = zz + i * n;
        double* ri = fraction > 0.0 ? scratch.data() : zi;
        const double decay = dt > 0.0 ? std::exp(-dt / tau_s) : 1.0;
        calib::ZeroResult r{};
        const auto run = [&](auto* rp) {
            r = calib::zero_frame(rp, n, seg, base, pk, fraction, decay, floor, margin, active, f,
                                  zi, ri, tmap.data(), m.data());
        };
        if (py::isinstance<py::array_t<std::uint16_t>>(raw) && (raw.flags() & py::array::c_style)) {
            run(static_cast<const std::uint16_t*>(raw.data()));
        } else if (py::isinstance<py::array_t<std::int64_t>>(raw) &&
                   (raw.flags() & py::array::c_style)) {
            run(static_cast<const std::int64_t*>(raw.data()));
        } else {  // any other counts: as float64, as zero_frame takes them
            auto d = py::array_t<double, py::array::c_style | py::array::forcecast>::ensure(raw);
            if (!d) throw py::type_error("raws: expected numeric counts");
            as_double.assign(d.data(), d.data() + n);
            run(as_double.data());
        }
        if (r.state < 0) break;  // a value the table cannot take: the reference path's frame
        ++taken;
        top = r.peak;
        ++frames;
        const bool settling = t < settle_until;
        last_t = t;
        residual_valid = (r.state & 1) != 0;
        if (residual_valid)
            for (py::ssize_t k = 0; k < n; ++k) res[k] = scratch[k];
        if (fraction > 0.0) active = (r.state & 2) != 0;
        bool contact = false;
        if (!settling) {
            double stat = r.statistic;
            if (average > 1) stat = calib::average_maps(rg, tot, tmap.data(), average, p, count, head);
            last_statistic = stat;
            det_in = det_in ? stat >= exit_ : stat > enter;
            contact = det_in;
        }
        st[i] = last_statistic;
        pks[i] = r.peak;
        if (contact) {
            in_contact = true;
            break;
        }
        if (in_contact) {
            in_contact = false;
            release_until = t + holdoff;
            released = true;
        }
        if (dt > 0.0) {
            const double tau = t < release_until ? tau_release : tau_drift;
            const double ema = -std::expm1(-dt / tau);
            const double mean = 1.0 / static_cast<double>(frames);
            const double sigma2 = std::pow(sigma, 2.0);
            if (mean >= ema) {
                calib::follow_baseline(base, zi, n, mean, 0.0, false);
                baseline_var = sigma2 * mean;
            } else {
                baseline_var = std::pow(1.0 - ema, 2.0) * baseline_var + ema * ema * sigma2;
                calib::follow_baseline(base, zi, n, ema, max_step, true);
            }
        }
    }
    s[0] = last_t;
    s[1] = static_cast<double>(frames);
    s[3] = release_until;
    s[4] = baseline_var;
    s[5] = in_contact ? 1.0 : 0.0;
    s[6] = active ? 1.0 : 0.0;
    s[7] = static_cast<double>(count);
    s[8] = static_cast<double>(head);
    s[9] = last_statistic;
    s[10] = det_in ? 1.0 : 0.0;
    s[11] = residual_valid ? 1.0 : 0.0;
    s[12] = top;
    s[13] = released ? 1.0 : 0.0;
    return taken;
}
}  // namespace

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
