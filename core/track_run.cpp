// A tracked contact's frames in one call (track_run): each frame through the calibration stage
// (ZeroRun::frame), then the tests ContactTracking.track makes before a step (another contact
// pressed outside the window, the signal grown past the fit's), the TrackStep of each tracked
// contact, and the estimate's numbers, into arrays Python publishes from.  The run stops at the
// first frame whose path differs from a tracked frame's (the contact ended, a test fires, a
// step answers anything but "tracked", the residuals' fold is due) with that frame zeroed but
// not tracked (a step it began is undone), and after a tracked frame the zeroer's drift step
// follows, or whose state wants a relinearisation: Python takes those frames (tactiled/pipeline/tracked_run.py),
// so every decision is the per-frame path's.
#include <pybind11/numpy.h>

#include <cmath>
#include <cstdint>
#include <limits>
#include <vector>

#include "arrays.hpp"
#include "pymath.hpp"
#include "stages.hpp"
#include "track_step.hpp"
#include "zero_run.hpp"

namespace py = pybind11;

namespace tactiled {
namespace {

// Why a run ended (tracked_run.STOPS, in this order).
enum Stop {
    STOP_READ = 0,      // the frames ran out, every one tracked
    STOP_UNTAKEN,       // a frame the compiled path does not take (not taken)
    STOP_ENDED,         // no contact: taken, the rest is Python's
    STOP_FOLD,          // the residuals' fold is due
    STOP_ELSEWHERE,     // pressed outside the window
    STOP_GROWN,         // the signal grew past the fit's
    STOP_UNMEASURED,    // a contact cannot measure it (a fit's)
    STOP_STEP,          // a step answered refit, a restart or a jump
    STOP_DRIFT,         // tracked, and the zeroer's drift step is due after it
    STOP_RELINEARIZE,   // tracked, and the state wants a relinearisation
};

// the run's scalars (tracked_run.TESTS, in this order)
enum Test {
    T_LIMIT = 0,    // frames the run may track (the residuals' fold after them)
    T_DRIFT_T,      // the zeroer's last drift step (s; +inf: none to follow, NaN: not started)
    T_DRIFT_STEP,   // DRIFT_STEP_S less its rounding
    T_ELSEWHERE,    // the strain over the expected outside the window that is another contact
    T_GROWN,        // the peak past which the signal has grown (NaN: no test)
    T_LIN_ASKED,    // device time a relinearisation was last asked for (s)
    T_MIN_RELIN,    // MIN_RELINEARIZE_S
    T_SIGMAS,       // RELINEARIZE_SIGMA
    T_SHARPEN,      // SHARPEN
    TEST_COUNT
};

py::tuple track_run(ZeroRun& runner, py::list raws, py::array times, py::array z,
                    py::array stats, py::array peaks, py::array state, py::list steps,
                    py::list ats, py::array per, In<double> tests, In<std::int64_t> outside,
                    In<double> expected, In<std::uint8_t> mask, py::array out) {
    const py::ssize_t frames = static_cast<py::ssize_t>(raws.size());
    const py::ssize_t n = runner.size();
    double* zz = data_of<double>(z, "z", true);
    const double* tm = data_of<double>(times, "times", false);
    double* st = data_of<double>(stats, "stats", true);
    double* pks = data_of<double>(peaks, "peaks", true);
    check_one_per_frame(frames, n, z, times, stats, peaks);
    if (tests.size() != TEST_COUNT) throw py::value_error("tests: one value per TESTS");
    const double* ts = tests.data();
    const py::ssize_t contacts = static_cast<py::ssize_t>(steps.size());
    if (contacts < 1 || static_cast<py::ssize_t>(ats.size()) != contacts)
        throw py::value_error("steps, ats: one per contact, at least one");
    std::vector<track::TrackStep*> step(static_cast<std::size_t>(contacts));
    std::vector<const double*> at(static_cast<std::size_t>(contacts));
    py::ssize_t kmax = 0;
    for (py::ssize_t c = 0; c < contacts; ++c) {
        step[c] = &steps[c].cast<track::TrackStep&>();
        at[c] = data_of<double>(ats[c].cast<py::array>(), "ats", false, step[c]->window());
        kmax = py_max(kmax, step[c]->params());
    }
    double* pr = data_of<double>(per, "per", true, 2 * contacts);  // (contacts, 2): last t, excess
    const py::ssize_t width = 14 + 2 * kmax;
    if (out.ndim() != 3 || out.shape(0) < frames || out.shape(1) != contacts ||
        out.shape(2) < width)
        throw py::value_error("out: shape (frames, contacts, 14 + 2 k)");
    double* o = data_of<double>(out, "out", true);
    const py::ssize_t row = out.shape(2);
    const py::ssize_t n_out = outside.size();
    if (expected.size() < n_out) throw py::value_error("expected: one value per outside index");
    const std::int64_t* ox = outside.data();
    for (py::ssize_t j = 0; j < n_out; ++j)
        if (ox[j] < 0 || ox[j] >= n) throw py::index_error("outside: index outside the frame");
    const double* ex = expected.data();
    const bool masked = mask.size() > 0;
    if (masked && mask.size() != n) throw py::value_error("mask: one value per tactel");
    const std::uint8_t* mk = mask.data();
    bool usable = false;
    for (py::ssize_t j = 0; masked && j < n; ++j) usable = usable || mk[j] != 0;

    ZeroState s = runner.load(state);
    std::vector<std::vector<double>> saved(static_cast<std::size_t>(contacts));
    std::int64_t taken = 0, tracked = 0;
    Stop stop = STOP_READ;
    for (py::ssize_t i = 0; i < frames; ++i) {
        const double t = tm[i];
        double* zi = zz + i * n;
        const ZeroStep zs = runner.frame(raws[i], t, zi, s, st[i], pks[i]);
        if (zs == ZERO_NOT_TAKEN) {
            stop = STOP_UNTAKEN;
            break;
        }
        ++taken;
        if (zs == ZERO_QUIET) {
            stop = STOP_ENDED;
            break;
        }
        if (!(static_cast<double>(i) < ts[T_LIMIT])) {
            stop = STOP_FOLD;
            break;
        }
        double top = -std::numeric_limits<double>::infinity();  // largest_excess
        for (py::ssize_t j = 0; j < n_out; ++j) top = py_max(top, zi[ox[j]] - ex[j]);
        if (top > ts[T_ELSEWHERE]) {
            stop = STOP_ELSEWHERE;
            break;
        }
        double peak = pks[i];  // SensorPipeline._frame_peak(w, 0.0)
        if (masked) {
            peak = 0.0;
            bool first = true;
            for (py::ssize_t j = 0; usable && j < n; ++j)
                if (mk[j] && (first || zi[j] > peak)) {
                    peak = zi[j];
                    first = false;
                }
        } else if (!(peak == peak)) {
            peak = zi[0];
            for (py::ssize_t j = 1; j < n; ++j) peak = zi[j] > peak ? zi[j] : peak;
        }
        if (peak > ts[T_GROWN]) {
            stop = STOP_GROWN;
            break;
        }
        for (py::ssize_t c = 0; c < contacts; ++c) step[c]->save(saved[c]);
        bool measured = true;
        for (py::ssize_t c = 0; c < contacts && measured; ++c)
            measured = step[c]->measure_frame(zi, n, at[c]);
        std::int64_t code = 0;
        for (py::ssize_t c = 0; c < contacts && measured && code == 0; ++c)
            code = step[c]->advance(t - pr[2 * c], false);
        if (!measured || code != 0) {
            for (py::ssize_t c = 0; c < contacts; ++c) step[c]->restore(saved[c]);
            stop = measured ? STOP_STEP : STOP_UNMEASURED;
            break;
        }
        ++tracked;
        bool moved = false;
        for (py::ssize_t c = 0; c < contacts; ++c) {
            pr[2 * c] = t;
            step[c]->estimate_into(0.0, pr[2 * c + 1], o + (i * contacts + c) * row);
            moved = moved || step[c]->moved(ts[T_SIGMAS], ts[T_SHARPEN]);
        }
        if (!(t - ts[T_DRIFT_T] < ts[T_DRIFT_STEP])) {
            stop = STOP_DRIFT;
            break;
        }
        if (moved && !(0.0 <= t - ts[T_LIN_ASKED] && t - ts[T_LIN_ASKED] < ts[T_MIN_RELIN])) {
            stop = STOP_RELINEARIZE;
            break;
        }
    }
    runner.store(s, state);
    return py::make_tuple(taken, tracked, static_cast<int>(stop));
}
}  // namespace

void bind_track_run(py::module_& m) {
    m.def("track_run", &track_run,
          "A tracked contact's frames in one call (tactiled.pipeline.tracked_run): "
          "(taken, tracked, stop).",
          py::arg("runner"), py::arg("raws"), py::arg("times"), py::arg("z"), py::arg("stats"),
          py::arg("peaks"), py::arg("state"), py::arg("steps"), py::arg("ats"), py::arg("per"),
          py::arg("tests"), py::arg("outside"), py::arg("expected"), py::arg("mask"),
          py::arg("out"));
}
}  // namespace tactiled
