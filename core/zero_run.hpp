// A run of frames through the calibration stage in one call (ZeroRun.run), and the step of one
// frame that the tracked run (core/track_run.cpp) shares with it.  Python reference:
// tactiled/calibration/fused_reference.py's ZeroRun (RUN_STATE, RUN_CONSTANTS name the vectors).
#pragma once
#include <pybind11/numpy.h>

#include <cstdint>
#include <vector>

#include "arrays.hpp"
#include "calibrate.hpp"

namespace tactiled {
namespace py = pybind11;

// RUN_STATE's and RUN_CONSTANTS' lengths (fused_reference.py)
constexpr py::ssize_t ZERO_STATE_SIZE = 14;
constexpr py::ssize_t ZERO_CONSTANT_SIZE = 12;

// The stage's state through a run (RUN_STATE, as numbers the loop reads).
struct ZeroState {
    double last_t = 0.0, settle_until = 0.0, release_until = 0.0, baseline_var = 0.0;
    std::int64_t frames = 0, count = 0, head = 0;
    bool in_contact = false, active = false, det_in = false, residual_valid = false,
         released = false;
    double last_statistic = 0.0, top = 0.0;
};

// What ZeroRun::frame did with a frame.
enum ZeroStep { ZERO_NOT_TAKEN = -1, ZERO_QUIET = 0, ZERO_CONTACT = 1 };

// One stage's run: its arrays and constants checked once (the table's segments, the
// baseline and peak-hold, the filter, the detector's ring), then a read's frames a call.
class ZeroRun {
public:
    ZeroRun(In<double> offset, In<double> breaks, In<std::int64_t> first, In<double> params,
            py::array baseline, py::array peak, In<double> ax, In<double> ay_t,
            In<std::int64_t> bands, py::array ring, py::array total, py::array residual,
            In<double> constants);

    // Frames until the first in contact (taken) or one the compiled path does not take.
    std::int64_t run(py::list raws, py::array times, py::array z, py::array stats,
                     py::array peaks, py::array state);

    // The state vector in and out (RUN_STATE).
    ZeroState load(py::array state) const;
    void store(const ZeroState& st, py::array state) const;

    // One frame: raw counts at device time t (s) zeroed into zi (n values); the detector's
    // statistic after it and its largest strain.  A contact frame leaves the baseline as it
    // is (frozen); a frame with no contact ends a contact and steps the baseline.
    ZeroStep frame(const py::handle& raw, double t, double* zi, ZeroState& s, double& stat,
                   double& peak);

    py::ssize_t size() const { return n_; }

private:
    std::vector<py::object> keep_;  // the arrays the pointers below point into
    py::ssize_t n_ = 0;
    calib::Segments seg_{};
    calib::Filter f_{};
    double *base_ = nullptr, *pk_ = nullptr, *res_ = nullptr, *rg_ = nullptr, *tot_ = nullptr;
    double c_[ZERO_CONSTANT_SIZE] = {};
    std::int64_t average_ = 1, p_ = 0;
    std::vector<double> tmap_, scratch_, m_, as_double_;
};

void check_one_per_frame(py::ssize_t frames, py::ssize_t n, const py::array& z,
                         const py::array& times, const py::array& stats, const py::array& peaks);
}  // namespace tactiled
