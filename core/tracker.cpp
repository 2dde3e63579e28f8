// The tracker's kernels (tracker.hpp) and their bindings, argument for argument those of
// tactiled/pipeline/kernels.py.  The state table and the residual sums are written in place,
// so an array of the wrong dtype or layout there is refused (TypeError), never silently
// copied; an index outside the frame is an IndexError, not a read out of bounds.
#include "tracker.hpp"

#include <pybind11/numpy.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>
#include <vector>

#include "arrays.hpp"
#include "pymath.hpp"
#include "stages.hpp"

namespace tactiled {
namespace tracker {
namespace {
// A float division by zero: the reference (Python floats) raises ZeroDivisionError there, and
// so does the core (translated in bind_tracker).
struct ZeroDivision : std::exception {
    const char* what() const noexcept override { return "float division by zero"; }
};

inline double divide(double a, double b) {
    if (b == 0.0) throw ZeroDivision();
    return a / b;
}

constexpr double PI = 3.141592653589793;
constexpr double RAD_TO_DEG = 180.0 / PI;
const double NaN = std::numeric_limits<double>::quiet_NaN();
}  // namespace

double measure_window(const double* frame, const std::int64_t* index, std::int64_t n,
                      const double* at, const double* gain, std::int64_t k,
                      const double* jacobian, const double* weight, double* dp, double* d) {
    for (std::int64_t j = 0; j < n; ++j) d[j] = frame[index[j]] - at[j];
    for (std::int64_t i = 0; i < k; ++i) {
        double s = 0.0;
        for (std::int64_t j = 0; j < n; ++j) s += gain[i * n + j] * d[j];
        dp[i] = s;
    }
    double chi2 = 0.0;
    for (std::int64_t j = 0; j < n; ++j) {
        double r = d[j];
        for (std::int64_t i = 0; i < k; ++i) r -= jacobian[j * k + i] * dp[i];
        d[j] = r;
        chi2 += r * r * weight[j];
    }
    return chi2;
}

bool measure_point(const double* frame, const std::int64_t* index, std::int64_t n,
                   const double* at, const double* gain, std::int64_t k, const double* jacobian,
                   const double* weight, const double* c, double limit, std::int64_t ln_f,
                   double reset_sigma, double max_log_force_step, double* dz, double* d) {
    const double chi2 = measure_window(frame, index, n, at, gain, k, jacobian, weight, dz, d);
    if (chi2 > limit) return false;
    for (std::int64_t i = 0; i < k; ++i)
        if (!std::isfinite(dz[i])) return false;
    for (std::int64_t i = 0; i < k; ++i) {
        const double step = std::fabs(dz[i]);
        if (c[C_LOG * k + i] != 0.0 && step >= 1.0 &&
            (step > reset_sigma * c[C_SD1 * k + i] || (i == ln_f && step > max_log_force_step)))
            return false;
    }
    for (std::int64_t i = 0; i < k; ++i)
        dz[i] = py_min(py_max(c[C_POINT * k + i] + dz[i], c[C_LOW * k + i]), c[C_HIGH * k + i]);
    return true;
}

std::int64_t filter_frame(const double* z, std::int64_t k, double* s, const double* c, double dt,
                          double acc_scale, double walk, bool fitted, double reset_sigma,
                          double drift_alpha, double drift_limit) {
    std::vector<double> xp(k), pxxp(k), pxvp(k), pvvp(k), u(k);
    const double dt2 = dt * dt, dt3 = dt * dt * dt;
    std::int64_t jumped = 0;
    auto S = [&](int row, std::int64_t i) -> double& { return s[row * k + i]; };
    auto C = [&](int row, std::int64_t i) { return c[row * k + i]; };
    for (std::int64_t i = 0; i < k; ++i) {
        const double ri = C(C_R, i);
        double x = S(X, i), pxx = S(PXX, i), pxv = S(PXV, i), pvv = S(PVV, i);
        if (C(C_MOVING, i) != 0.0) {
            const double acc = acc_scale * ri;
            x += S(V, i) * dt;
            pxx += 2.0 * dt * pxv + dt2 * pvv + acc * dt3 / 3.0;
            pxv += dt * pvv + acc * dt2 / 2.0;
            pvv += acc * dt;
        } else {
            pxx += ri * walk;
        }
        xp[i] = x;
        pxxp[i] = pxx;
        pxvp[i] = pxv;
        pvvp[i] = pvv;
        u[i] = divide(z[i] - x, std::sqrt(pxx + ri));
        if (std::fabs(u[i]) > reset_sigma) jumped |= std::int64_t{1} << i;
    }
    if (jumped && !fitted) return -1;
    for (std::int64_t i = 0; i < k; ++i) {
        S(X, i) = xp[i];
        S(PXX, i) = pxxp[i];
        S(PXV, i) = pxvp[i];
        S(PVV, i) = pvvp[i];
    }
    if (jumped) return jumped;
    for (std::int64_t i = 0; i < k; ++i) {
        const double ri = C(C_R, i);
        double x = S(X, i), v = S(V, i), pxx = S(PXX, i), pxv = S(PXV, i), pvv = S(PVV, i),
               drift = S(DRIFT, i);
        const double total = pxx + ri;
        const double k1 = divide(pxx, total), k2 = divide(pxv, total);
        const double nu = z[i] - x;
        x += k1 * nu;
        v += k2 * nu;
        pvv -= k2 * pxv;
        pxx *= 1.0 - k1;
        pxv *= 1.0 - k1;
        drift += drift_alpha * (u[i] - drift);
        if (std::fabs(drift) > drift_limit) {
            if (C(C_MOVING, i) != 0.0) {
                const double window = divide(dt, drift_alpha);
                const double lag = divide(drift * std::sqrt(total), window);
                pvv = py_max(pvv, 16.0 * (lag * lag));
            } else {
                pxx = py_max(pxx, total);
            }
            drift = 0.0;
        }
        S(X, i) = x;
        S(V, i) = v;
        S(PXX, i) = pxx;
        S(PXV, i) = pxv;
        S(PVV, i) = pvv;
        S(DRIFT, i) = drift;
    }
    return 0;
}

namespace {
// The covariance of values ka and kb from their gradient terms (kernels._delta_cov).
double delta_cov(const std::int64_t* idx, const double* grad, int ka, int kb, const double* sd,
                 const double* corr, const double* sys, bool has_sys, std::int64_t k) {
    double total = 0.0;
    for (int ia = 0; ia < 2; ++ia) {
        const std::int64_t a = idx[ka * 2 + ia];
        if (a < 0) break;
        const double ga = grad[ka * 2 + ia];
        const double gsa = ga * sd[a];
        for (int ib = 0; ib < 2; ++ib) {
            const std::int64_t b = idx[kb * 2 + ib];
            if (b < 0) break;
            const double gb = grad[kb * 2 + ib];
            total += gsa * (gb * sd[b]) * corr[a * k + b];
            if (has_sys) total += ga * gb * sys[a * k + b];
        }
    }
    return total;
}

// A held parameter's lag (kernels.held_lag): the squared mean innovation its drift detector
// shows for the frames it has gathered, where significant (kernels.HELD_LAG_SCALE); else 0.
constexpr double HELD_LAG_SCALE = 2.25;
double held_lag(double drift, double pxx, double r, double lag_noise, double alpha) {
    if (!(drift * drift > 0.0 && pxx > 0.0)) return 0.0;
    const double q = std::pow(1.0 - alpha, std::max(r / pxx, 1.0));
    if (!(drift * drift > HELD_LAG_SCALE * lag_noise * (1.0 - q * q))) return 0.0;
    const double m = drift / (1.0 - q);
    return m * m;
}
}  // namespace

std::int64_t estimate_numbers(std::int64_t model, const double* s, std::int64_t k, const double* c,
                              double dt, double excess, const double* corr, const double* sys,
                              bool has_sys, double lag_noise, double drift_alpha, double* values,
                              double* var, double& cov_rf) {
    std::vector<double> x(k), pxx(k), sd(k);
    auto S = [&](int row, std::int64_t i) { return s[row * k + i]; };
    for (std::int64_t i = 0; i < k; ++i) {
        if (dt != 0.0) {
            x[i] = S(X, i) + S(V, i) * dt;
            pxx[i] = S(PXX, i) + dt * (2.0 * S(PXV, i) + dt * S(PVV, i));
        } else {
            x[i] = S(X, i);
            pxx[i] = S(PXX, i);
        }
    }
    for (std::int64_t i = 0; i < k; ++i) {
        const double d = S(DRIFT, i);
        const double r = c[C_R * k + i];
        if (c[C_MOVING * k + i] != 0.0) {
            if (d * d > lag_noise) pxx[i] = pxx[i] + d * d * (pxx[i] + r);
        } else {
            pxx[i] = pxx[i] + held_lag(d, pxx[i], r, lag_noise, drift_alpha) * (pxx[i] + r);
        }
    }
    for (std::int64_t i = 0; i < k; ++i) {
        const double q = pxx[i] * excess;
        sd[i] = q >= 0.0 ? std::sqrt(q) : NaN;
    }
    std::int64_t idx[12];
    double grad[12];
    for (int i = 0; i < 12; ++i) {
        idx[i] = -1;
        grad[i] = 0.0;
    }
    for (int i = 0; i < 6; ++i) values[i] = NaN;
    std::int64_t absent = 0;
    const double f = std::exp(x[k - 3]);
    values[0] = x[k - 2];
    values[1] = x[k - 1];
    values[2] = f;
    idx[0] = k - 2, grad[0] = 1.0;
    idx[2] = k - 1, grad[2] = 1.0;
    idx[4] = k - 3, grad[4] = f;
    if (model == 0) {  // cylinder: ln_r, psi, ln_f, x0, y0
        const double r = std::exp(x[0]);
        values[3] = r;
        values[5] = x[1];
        idx[6] = 0, grad[6] = r;
        idx[10] = 1, grad[10] = RAD_TO_DEG;
        absent = 1 << 4;
    } else if (model == 1) {  // sphere: ln_r, ln_f, x0, y0
        const double r = std::exp(x[0]);
        values[3] = r;
        values[4] = r;
        idx[6] = 0, grad[6] = r;
        idx[8] = 0, grad[8] = r;
        absent = 1 << 5;
    } else {  // general: ln_ra, beta, psi, ln_f, x0, y0
        const double ra = std::exp(x[0]), beta = x[1];
        const double b2 = beta * beta;
        double psi = x[2];
        if (b2 <= 1.0) {
            values[3] = ra;
            idx[6] = 0, grad[6] = ra;
            if (b2 > 0.0) {
                const double r2 = ra / b2;
                values[4] = r2;
                idx[8] = 0, grad[8] = r2;
                idx[9] = 1, grad[9] = -2.0 * r2 / beta;
            } else {
                absent = 1 << 4;
            }
        } else {
            const double r1 = ra / b2;
            values[3] = r1;
            values[4] = ra;
            idx[6] = 0, grad[6] = r1;
            idx[7] = 1, grad[7] = -2.0 * r1 / beta;
            idx[8] = 0, grad[8] = ra;
            psi += 0.5 * PI;
        }
        values[5] = psi;
        idx[10] = 2, grad[10] = RAD_TO_DEG;
    }
    for (int key = 0; key < 6; ++key)
        var[key] = idx[key * 2] >= 0
                       ? delta_cov(idx, grad, key, key, sd.data(), corr, sys, has_sys, k)
                       : NaN;
    cov_rf = idx[6] >= 0 ? delta_cov(idx, grad, 3, 2, sd.data(), corr, sys, has_sys, k) : NaN;
    return absent;
}

bool moved_from_point(const double* st, std::int64_t k, const double* c, double sigmas,
                      double sharpen) {
    for (std::int64_t i = 0; i < k; ++i) {
        const double lin_sd = c[C_LIN_SD * k + i];
        if (std::fabs(st[X * k + i] - c[C_POINT * k + i]) > sigmas * c[C_SD1 * k + i] ||
            !(lin_sd == lin_sd) || sharpen * sharpen * st[PXX * k + i] < lin_sd * lin_sd)
            return true;
    }
    return false;
}
}  // namespace tracker

namespace {
using namespace tracker;

// A flat frame and the window's indices into it: every index inside the frame.
const std::int64_t* checked_index(const In<double>& frame, const In<std::int64_t>& index) {
    const std::int64_t* ix = index.data();
    const py::ssize_t size = frame.size();
    for (py::ssize_t j = 0; j < index.size(); ++j)
        if (ix[j] < 0 || ix[j] >= size) throw py::index_error("index outside the frame");
    return ix;
}

// A (rows, cols) table of the given shape (a ValueError otherwise).
void need_shape(const py::array& a, const char* name, py::ssize_t rows, py::ssize_t cols) {
    if (a.ndim() != 2 || a.shape(0) != rows || a.shape(1) != cols)
        throw py::value_error(std::string(name) + ": expected shape (" + std::to_string(rows) +
                              ", " + std::to_string(cols) + ")");
}

struct Window {
    py::ssize_t n, k;
};

Window window_shapes(const In<double>& frame, const In<std::int64_t>& index, const In<double>& at,
                     const In<double>& gain, const In<double>& jacobian, const In<double>& weight) {
    if (frame.ndim() != 1 || index.ndim() != 1) throw py::value_error("frame, index: expected flat arrays");
    const py::ssize_t n = index.size();
    if (gain.ndim() != 2) throw py::value_error("gain: expected a (k, n) matrix");
    const py::ssize_t k = gain.shape(0);
    need_shape(gain, "gain", k, n);
    need_shape(jacobian, "jacobian", n, k);
    if (at.size() != n || weight.size() != n) throw py::value_error("at, weight: one value per index");
    checked_index(frame, index);
    return {n, k};
}

py::tuple measure_window_py(In<double> frame, In<std::int64_t> index, In<double> at,
                            In<double> gain, In<double> jacobian, In<double> weight) {
    const Window w = window_shapes(frame, index, at, gain, jacobian, weight);
    py::array_t<double> dp(w.k), e(w.n);
    const double chi2 = measure_window(frame.data(), index.data(), w.n, at.data(), gain.data(),
                                       w.k, jacobian.data(), weight.data(), dp.mutable_data(),
                                       e.mutable_data());
    return py::make_tuple(chi2, dp, e);
}

double largest_excess_py(In<double> frame, In<std::int64_t> index, In<double> expected) {
    if (expected.size() < index.size()) throw py::value_error("expected: one value per index");
    const std::int64_t* ix = checked_index(frame, index);
    const double* f = frame.data();
    const double* ex = expected.data();
    double top = -std::numeric_limits<double>::infinity();
    for (py::ssize_t j = 0; j < index.size(); ++j) top = py_max(top, f[ix[j]] - ex[j]);
    return top;
}

py::tuple fold_residuals_py(py::array total, py::array count, In<std::int64_t> index,
                            py::array buffered, double frames, double fade, double least) {
    const py::ssize_t size = total.size();
    double* tot = data_of<double>(total, "total", true);
    double* cnt = data_of<double>(count, "count", true, size);
    const py::ssize_t n = index.size();
    double* buf = data_of<double>(buffered, "buffered", true, n);
    const std::int64_t* ix = index.data();
    for (py::ssize_t j = 0; j < n; ++j)
        if (ix[j] < 0 || ix[j] >= size) throw py::index_error("index outside the frame");
    for (py::ssize_t i = 0; i < size; ++i) {
        tot[i] *= fade;
        cnt[i] *= fade;
    }
    for (py::ssize_t j = 0; j < n; ++j) {
        tot[ix[j]] += buf[j];
        cnt[ix[j]] += frames;
        buf[j] = 0.0;
    }
    std::int64_t used = 0;
    double chi2 = 0.0;
    for (py::ssize_t i = 0; i < size; ++i)
        if (cnt[i] >= least) {
            ++used;
            chi2 += divide(tot[i] * tot[i], cnt[i]);
        }
    return py::make_tuple(used, chi2);
}

py::tuple linearization_constants_py(In<double> table, In<double> cov, In<double> p, In<double> s,
                                     In<double> systematic, double zero_scale) {
    const py::ssize_t k = p.size();
    need_shape(table, "table", 8, k);
    need_shape(cov, "cov", k, k);
    need_shape(systematic, "systematic", k, k);
    if (s.ndim() != 2 || s.shape(0) != 6) throw py::value_error("s: expected shape (6, k)");
    const bool with_state = s.shape(1) == k;
    py::array_t<double> c({py::ssize_t{8}, k}), corr({k, k}), sys({k, k});
    double* cc = c.mutable_data();
    std::copy(table.data(), table.data() + 8 * k, cc);
    const double* cv = cov.data();
    for (py::ssize_t i = 0; i < k; ++i) {
        const double r = cv[i * k + i];
        cc[C_R * k + i] = r;
        cc[C_SD1 * k + i] = std::sqrt(r);
        cc[C_POINT * k + i] = p.data()[i];
        cc[C_LIN_SD * k + i] = with_state ? std::sqrt(s.data()[PXX * k + i]) : NaN;
    }
    double* co = corr.mutable_data();
    double* sy = sys.mutable_data();
    const double* sm = systematic.data();
    bool nonzero = false;
    for (py::ssize_t i = 0; i < k; ++i)
        for (py::ssize_t j = 0; j < k; ++j) {
            co[i * k + j] = divide(cv[i * k + j], cc[C_SD1 * k + i] * cc[C_SD1 * k + j]);
            const double v = sm[i * k + j] + zero_scale * cv[i * k + j];
            sy[i * k + j] = v;
            nonzero = nonzero || v != 0.0;
        }
    return py::make_tuple(c, corr, sys, nonzero);
}

py::tuple measure_point_py(In<double> frame, In<std::int64_t> index, In<double> at,
                           In<double> gain, In<double> jacobian, In<double> weight,
                           In<double> cst, double limit, std::int64_t ln_f, double reset_sigma,
                           double max_log_force_step) {
    const Window w = window_shapes(frame, index, at, gain, jacobian, weight);
    const py::ssize_t k = w.k;
    need_shape(cst, "const", 8, k);
    py::array_t<double> dzarr(k), e(w.n);
    const bool ok = measure_point(frame.data(), index.data(), w.n, at.data(), gain.data(), k,
                                  jacobian.data(), weight.data(), cst.data(), limit, ln_f,
                                  reset_sigma, max_log_force_step, dzarr.mutable_data(),
                                  e.mutable_data());
    return py::make_tuple(ok, dzarr, e);
}

std::int64_t filter_frame_py(In<double> z, py::array s, In<double> cst, double dt,
                             double acc_scale, double walk, bool fitted, double reset_sigma,
                             double drift_alpha, double drift_limit) {
    const py::ssize_t k = z.size();
    if (k > 62) throw py::value_error("z: at most 62 parameters (a bit each in the result)");
    need_shape(s, "s", 6, k);
    need_shape(cst, "const", 8, k);
    double* st = data_of<double>(s, "s", true);
    return filter_frame(z.data(), k, st, cst.data(), dt, acc_scale, walk, fitted, reset_sigma,
                        drift_alpha, drift_limit);
}

bool moved_from_point_py(In<double> s, In<double> cst, double sigmas, double sharpen) {
    if (s.ndim() != 2 || s.shape(0) != 6) throw py::value_error("s: expected shape (6, k)");
    const py::ssize_t k = s.shape(1);
    need_shape(cst, "const", 8, k);
    return moved_from_point(s.data(), k, cst.data(), sigmas, sharpen);
}

py::tuple estimate_numbers_py(std::int64_t model, In<double> s, In<double> cst, double dt,
                              double excess, In<double> corr, In<double> sys, bool has_sys,
                              double lag_noise, double drift_alpha) {
    if (s.ndim() != 2 || s.shape(0) != 6) throw py::value_error("s: expected shape (6, k)");
    const py::ssize_t k = s.shape(1);
    const py::ssize_t least = model == 2 ? 6 : model == 0 ? 5 : 4;
    if (k < least) throw py::value_error("s: fewer parameters than the model has");
    need_shape(cst, "const", 8, k);
    need_shape(corr, "corr", k, k);
    need_shape(sys, "sys", k, k);
    py::array_t<double> values(6), var(6);
    double cov_rf = 0.0;
    const std::int64_t absent =
        estimate_numbers(model, s.data(), k, cst.data(), dt, excess, corr.data(), sys.data(),
                         has_sys, lag_noise, drift_alpha, values.mutable_data(),
                         var.mutable_data(), cov_rf);
    return py::make_tuple(values, var, cov_rf, absent);
}
}  // namespace

void bind_tracker(py::module_& m) {
    py::register_exception_translator([](std::exception_ptr p) {
        try {
            if (p) std::rethrow_exception(p);
        } catch (const ZeroDivision& e) {
            PyErr_SetString(PyExc_ZeroDivisionError, e.what());
        }
    });
    m.def("measure_window", &measure_window_py,
          "One frame through a linearisation (tactiled.pipeline.kernels.measure_window).");
    m.def("largest_excess", &largest_excess_py,
          "max(frame[index] - expected) (tactiled.pipeline.kernels.largest_excess).");
    m.def("fold_residuals", &fold_residuals_py,
          "The tracker's per-tactel residual sums (tactiled.pipeline.kernels.fold_residuals).");
    m.def("linearization_constants", &linearization_constants_py,
          "A tracker's constants for a new linearisation (kernels.linearization_constants).");
    m.def("measure_point", &measure_point_py,
          "measure_window and the tracker's tests of the step (kernels.measure_point).");
    m.def("filter_frame", &filter_frame_py,
          "One measurement through the per-parameter filters (kernels.filter_frame).");
    m.def("moved_from_point", &moved_from_point_py,
          "The state has moved from the linearisation point (kernels.moved_from_point).");
    m.def("estimate_numbers", &estimate_numbers_py,
          "The numbers of a tracker's estimate (kernels.estimate_numbers).");
}
}  // namespace tactiled
