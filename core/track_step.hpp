// A tracked contact's frame in one call: measured through the contact's linearisation, its
// residual buffered, the per-parameter filters stepped, the lag's running means updated.
// Python reference: tactiled/pipeline/kernels.py's TrackStep (same arguments, same order of
// operations; tests/native/test_track_step.py).
#pragma once
#include <pybind11/numpy.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <string>
#include <vector>

#include "arrays.hpp"
#include "pymath.hpp"
#include "tracker.hpp"

namespace tactiled {
namespace track {

// TrackStep.advance's answers besides 0 (updated) and a jump's bit mask (> 0)
constexpr std::int64_t STEP_UNMEASURED = -1;
constexpr std::int64_t STEP_REFIT = -2;
constexpr std::int64_t STEP_RESTART = -3;

// The scalar constants (kernels.TRACK_CONSTANTS), in that order.
struct Constants {
    double limit;
    std::int64_t ln_f;
    double reset_sigma, max_log_force_step;
    std::int64_t beta_i;
    double beta_sign, memory_s, hold_s, drift_alpha, drift_limit, lag_weight, lag_significant,
        max_gap_s;
    std::int64_t model;
    bool has_sys;
    double lag_noise;
};
constexpr int CONSTANT_COUNT = 16;

// Per parameter, the lag's variance (kernels.lag_variance): lag (2, k) -> out (k).
void lag_variance(const double* lag, std::int64_t k, double weight, double significant,
                  double* out);

namespace py = pybind11;
using namespace tracker;

constexpr double RAD_TO_DEG_TRACK = 180.0 / 3.141592653589793;

inline void need_shape(const py::array& a, const char* name, py::ssize_t rows, py::ssize_t cols) {
    if (a.ndim() != 2 || a.shape(0) != rows || a.shape(1) != cols)
        throw py::value_error(std::string(name) + ": expected shape (" + std::to_string(rows) +
                              ", " + std::to_string(cols) + ")");
}

class TrackStep {
public:
    TrackStep(py::array s, py::array lag, py::array c, py::array z, py::array ebuf,
              py::array index, py::array at, py::array gain, py::array jacobian, py::array weight,
              py::array corr, py::array sys, py::array lag_key, py::tuple constants)
        : keep_{s, lag, c, z, ebuf, index, at, gain, jacobian, weight, corr, sys, lag_key} {
        k_ = z.size();
        n_ = index.size();
        if (k_ < 1 || k_ > 62) throw py::value_error("z: 1 to 62 parameters");
        need_shape(s, "s", 6, k_);
        need_shape(lag, "lag", 2, k_);
        need_shape(c, "c", 8, k_);
        need_shape(gain, "gain", k_, n_);
        need_shape(jacobian, "jacobian", n_, k_);
        need_shape(corr, "corr", k_, k_);
        need_shape(sys, "sys", k_, k_);
        s_ = data_of<double>(s, "s", true);
        lag_ = data_of<double>(lag, "lag", true);
        c_ = data_of<double>(c, "c", false);
        z_ = data_of<double>(z, "z", true);
        ebuf_ = data_of<double>(ebuf, "ebuf", true, n_);
        ix_ = data_of<std::int64_t>(index, "index", false);
        at_ = data_of<double>(at, "at", false, n_);
        gain_ = data_of<double>(gain, "gain", false);
        jac_ = data_of<double>(jacobian, "jacobian", false);
        w_ = data_of<double>(weight, "weight", false, n_);
        corr_ = data_of<double>(corr, "corr", false);
        sys_ = data_of<double>(sys, "sys", false);
        lag_key_ = data_of<std::int64_t>(lag_key, "lag_key", false, k_);
        for (py::ssize_t i = 0; i < k_; ++i)
            if (lag_key_[i] < -1 || lag_key_[i] > 5) throw py::value_error("lag_key: -1 to 5");
        if (constants.size() != CONSTANT_COUNT)
            throw py::value_error("constants: expected " + std::to_string(CONSTANT_COUNT));
        double v[CONSTANT_COUNT];
        for (int i = 0; i < CONSTANT_COUNT; ++i) v[i] = constants[i].cast<double>();
        k.limit = v[0];
        k.ln_f = static_cast<std::int64_t>(v[1]);
        k.reset_sigma = v[2];
        k.max_log_force_step = v[3];
        k.beta_i = static_cast<std::int64_t>(v[4]);
        k.beta_sign = v[5];
        k.memory_s = v[6];
        k.hold_s = v[7];
        k.drift_alpha = v[8];
        k.drift_limit = v[9];
        k.lag_weight = v[10];
        k.lag_significant = v[11];
        k.max_gap_s = v[12];
        k.model = static_cast<std::int64_t>(v[13]);
        k.has_sys = v[14] != 0.0;
        k.lag_noise = v[15];
        const py::ssize_t least = k.model == 2 ? 6 : k.model == 0 ? 5 : 4;
        if (k.model < 0 || k.model > 2 || k_ < least)
            throw py::value_error("model: a code of kernels.MODEL_CODES with its parameters");
        if (k.beta_i >= k_) throw py::value_error("beta_i: outside the parameters");
        max_ix_ = -1;
        for (py::ssize_t j = 0; j < n_; ++j) {
            if (ix_[j] < 0) throw py::index_error("index outside the frame");
            if (ix_[j] > max_ix_) max_ix_ = ix_[j];
        }
        e_.assign(static_cast<std::size_t>(n_), 0.0);
        dz_.assign(static_cast<std::size_t>(k_), 0.0);
        nu_.assign(static_cast<std::size_t>(2 * k_), 0.0);
        extra_.assign(static_cast<std::size_t>(k_), 0.0);
    }

    // TrackStep.measure: frame (flat) less at, through the linearisation.
    bool measure(const py::array& frame, const py::array& at) {
        const double* f = data_of<double>(frame, "frame", false);
        if (max_ix_ >= frame.size()) throw py::index_error("index outside the frame");
        const double* a = at.is(keep_[6]) ? at_ : data_of<double>(at, "at", false, n_);
        return measure_raw(f, a);
    }

    // TrackStep.advance: the filters stepped with z, dt s after their last frame.
    std::int64_t advance(double dt, bool fitted) {
        if (!fitted)
            for (py::ssize_t j = 0; j < n_; ++j) ebuf_[j] += e_[j];
        if (!(0.0 < dt && dt < k.max_gap_s)) return STEP_RESTART;
        const double a = 2.0 * dt, b = dt * dt;
        double* nu = nu_.data();  // (2, k): the innovation, its predicted variance
        for (py::ssize_t i = 0; i < k_; ++i) {
            const bool moving = c_[C_MOVING * k_ + i] != 0.0;
            nu[i] = moving ? z_[i] - (s_[X * k_ + i] + s_[V * k_ + i] * dt) : 0.0;
            nu[k_ + i] = moving ? ((s_[PXX * k_ + i] + a * s_[PXV * k_ + i]) +
                                   b * s_[PVV * k_ + i]) + c_[C_R * k_ + i]
                                : 0.0;
        }
        const double m4 = std::pow(k.memory_s, 4.0);
        const std::int64_t jumped =
            filter_frame(z_, k_, s_, c_, dt, 36.0 * dt / m4, dt * dt / (k.hold_s * k.hold_s),
                         fitted, k.reset_sigma, k.drift_alpha, k.drift_limit);
        if (jumped < 0) return STEP_REFIT;
        if (jumped) return jumped;
        for (py::ssize_t j = 0; j < 2 * k_; ++j) lag_[j] += k.lag_weight * (nu[j] - lag_[j]);
        lag_variance(lag_, k_, k.lag_weight, k.lag_significant, extra_.data());
        bool any = false;
        for (py::ssize_t i = 0; i < k_; ++i) any = any || extra_[i] != 0.0;
        if (any) {
            const double m2 = k.memory_s * k.memory_s;
            for (py::ssize_t i = 0; i < k_; ++i) s_[PVV * k_ + i] += extra_[i] / m2;
        }
        return 0;
    }

    std::int64_t step(const py::array& frame, double dt) {
        const double* f = data_of<double>(frame, "frame", false);
        if (max_ix_ >= frame.size()) throw py::index_error("index outside the frame");
        if (!measure_raw(f, at_)) return STEP_UNMEASURED;
        return advance(dt, false);
    }

    // TrackStep.estimate: the estimate's numbers dt s ahead, the lag in each moving value's
    // variance; (values, variances, cov_r1_force, absent), lists of 6.
    py::tuple estimate(double dt, double excess) {
        double values[6], var[6], cov_rf = 0.0;
        const std::int64_t absent = estimate_raw(dt, excess, values, var, cov_rf);
        py::list vl(6), vr(6);
        for (int i = 0; i < 6; ++i) {
            vl[i] = py::float_(values[i]);
            vr[i] = py::float_(var[i]);
        }
        return py::make_tuple(vl, vr, cov_rf, absent);
    }

    py::array s() const { return keep_[0]; }
    py::array lag() const { return keep_[1]; }
    py::array z() const { return keep_[3]; }
    py::array ebuf() const { return keep_[4]; }

    // --- the tracked run's side (core/track_run.cpp): the same steps on raw pointers ---

    // measure, on a frame of `size` values (flat), the window less `at` (n values)
    bool measure_frame(const double* f, py::ssize_t size, const double* at) {
        if (max_ix_ >= size) throw py::index_error("index outside the frame");
        return measure_raw(f, at);
    }
    const double* at_data() const { return at_; }
    py::ssize_t window() const { return n_; }
    py::ssize_t params() const { return k_; }

    // What a step writes (s, lag, z, ebuf), kept so a step the run does not take is undone.
    void save(std::vector<double>& out) const {
        out.assign(s_, s_ + 6 * k_);
        out.insert(out.end(), lag_, lag_ + 2 * k_);
        out.insert(out.end(), z_, z_ + k_);
        out.insert(out.end(), ebuf_, ebuf_ + n_);
    }
    void restore(const std::vector<double>& in) {
        const double* p = in.data();
        std::copy(p, p + 6 * k_, s_);
        std::copy(p + 6 * k_, p + 8 * k_, lag_);
        std::copy(p + 8 * k_, p + 9 * k_, z_);
        std::copy(p + 9 * k_, p + 9 * k_ + n_, ebuf_);
    }

    // estimate's numbers into out: values (6), variances (6), cov_r1_force, absent, then the
    // state's rates (k) and their variances (k)
    void estimate_into(double dt, double excess, double* out) {
        double cov_rf = 0.0;
        const std::int64_t absent = estimate_raw(dt, excess, out, out + 6, cov_rf);
        out[12] = cov_rf;
        out[13] = static_cast<double>(absent);
        for (py::ssize_t i = 0; i < k_; ++i) {
            out[14 + i] = s_[V * k_ + i];
            out[14 + k_ + i] = s_[PVV * k_ + i];
        }
    }

    // kernels.moved_from_point on the state: a relinearisation is wanted
    bool moved(double sigmas, double sharpen) const {
        return moved_from_point(s_, k_, c_, sigmas, sharpen);
    }

private:
    std::int64_t estimate_raw(double dt, double excess, double* values, double* var,
                              double& cov_rf) {
        const std::int64_t absent =
            estimate_numbers(k.model, s_, k_, c_, dt, excess, corr_, sys_, k.has_sys,
                             k.lag_noise, k.drift_alpha, values, var, cov_rf);
        lag_variance(lag_, k_, k.lag_weight, k.lag_significant, extra_.data());
        for (py::ssize_t i = 0; i < k_; ++i) {
            const std::int64_t key = lag_key_[i];
            if (extra_[i] > 0.0 && key >= 0) {
                const double unit = key == 2 ? values[2] : key == 5 ? RAD_TO_DEG_TRACK : 1.0;
                var[key] += extra_[i] * unit * unit;
            }
        }
        return absent;
    }

    bool measure_raw(const double* f, const double* at) {
        double* d = e_.data();
        double* dz = dz_.data();
        if (!measure_point(f, ix_, n_, at, gain_, k_, jac_, w_, c_, k.limit, k.ln_f,
                           k.reset_sigma, k.max_log_force_step, dz, d))
            return false;
        if (k.beta_i >= 0)  // (the strain has beta^2 only: an elongated contact keeps its axes)
            dz[k.beta_i] = k.beta_sign * py_max(std::fabs(dz[k.beta_i]), 1.0);
        for (py::ssize_t i = 0; i < k_; ++i) z_[i] = dz[i];
        return true;
    }

    py::array keep_[13];
    py::ssize_t k_ = 0, n_ = 0;
    std::int64_t max_ix_ = -1;
    Constants k{};
    double *s_, *lag_, *z_, *ebuf_;
    const double *c_, *at_, *gain_, *jac_, *w_, *corr_, *sys_;
    const std::int64_t *ix_, *lag_key_;
    std::vector<double> e_, dz_, nu_, extra_;
};
}  // namespace track
}  // namespace tactiled
