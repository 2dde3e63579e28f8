// The least-squares pieces (lsq.hpp) and their bindings.
#include "lsq.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

#include "arrays.hpp"
#include "stages.hpp"

namespace tactiled {
namespace {
const double INF = std::numeric_limits<double>::infinity();
const double NaN = std::numeric_limits<double>::quiet_NaN();
}  // namespace

void normal_equations(const double* jac, const double* r, int n, int k, std::vector<double>& jtj,
                      std::vector<double>& g, std::vector<double>& diag) {
    jtj.assign(static_cast<size_t>(k) * k, 0.0);
    g.assign(k, 0.0);
    diag.assign(k, 0.0);
    for (int i = 0; i < k; ++i) {
        for (int j = 0; j < k; ++j) {
            double acc = 0.0;
            for (int row = 0; row < n; ++row) acc += jac[row * k + i] * jac[row * k + j];
            jtj[i * k + j] = acc;
        }
        double acc = 0.0;
        for (int row = 0; row < n; ++row) acc += jac[row * k + i] * r[row];
        g[i] = acc;
    }
    double top = 0.0;
    for (int i = 0; i < k; ++i) top = std::max(top, jtj[i * k + i]);
    const double floor = 1e-12 * std::max(top, 1e-300);
    for (int i = 0; i < k; ++i) diag[i] = std::max(jtj[i * k + i], floor);
}

double finite_cost(const double* r, int n, const double* jac, int jac_size) {
    double sum = 0.0;
    for (int i = 0; i < jac_size; ++i) sum += jac[i];
    if (!std::isfinite(sum)) return INF;
    double c = 0.0;
    for (int i = 0; i < n; ++i) c += r[i] * r[i];
    return std::isfinite(c) ? c : INF;
}

bool lu_solve(std::vector<double> a, std::vector<double> b, int k, std::vector<double>& x) {
    for (int col = 0; col < k; ++col) {
        int piv = col;
        for (int row = col + 1; row < k; ++row)
            if (std::fabs(a[row * k + col]) > std::fabs(a[piv * k + col])) piv = row;
        if (a[piv * k + col] == 0.0) return false;
        if (piv != col) {
            for (int j = 0; j < k; ++j) std::swap(a[col * k + j], a[piv * k + j]);
            std::swap(b[col], b[piv]);
        }
        for (int row = col + 1; row < k; ++row) {
            const double f = a[row * k + col] / a[col * k + col];
            for (int j = col + 1; j < k; ++j) a[row * k + j] -= f * a[col * k + j];
            b[row] -= f * b[col];
        }
    }
    x.assign(k, 0.0);
    for (int i = k - 1; i >= 0; --i) {
        double acc = b[i];
        for (int j = i + 1; j < k; ++j) acc -= a[i * k + j] * x[j];
        x[i] = acc / a[i * k + i];
    }
    return true;
}

bool damped_step(const std::vector<double>& jtj, const std::vector<double>& g,
                 const std::vector<double>& diag, double lam, const double* scale, int k,
                 std::vector<double>& step, double& over, double& predicted) {
    std::vector<double> a(jtj);
    for (int i = 0; i < k; ++i) a[i * k + i] += lam * diag[i];
    if (!lu_solve(a, g, k, step)) return false;
    for (int i = 0; i < k; ++i) step[i] = -step[i];
    over = 0.0;
    for (int i = 0; i < k; ++i) over = std::max(over, std::fabs(step[i]) / scale[i]);
    if (over > 1.0) {
        for (int i = 0; i < k; ++i) step[i] /= over;
        over = 1.0;
    }
    double gs = 0.0, sjs = 0.0;
    for (int i = 0; i < k; ++i) {
        gs += g[i] * step[i];
        double row = 0.0;
        for (int j = 0; j < k; ++j) row += jtj[i * k + j] * step[j];
        sjs += step[i] * row;
    }
    predicted = -(2.0 * gs + sjs);
    return true;
}

void symmetric_eigen(std::vector<double> a, int k, std::vector<double>& ev, std::vector<double>& vec) {
    vec.assign(static_cast<size_t>(k) * k, 0.0);
    for (int i = 0; i < k; ++i) vec[i * k + i] = 1.0;
    for (int sweep = 0; sweep < 100; ++sweep) {
        double off = 0.0;
        for (int i = 0; i < k; ++i)
            for (int j = i + 1; j < k; ++j) off += a[i * k + j] * a[i * k + j];
        if (off == 0.0) break;
        for (int p = 0; p < k; ++p) {
            for (int q = p + 1; q < k; ++q) {
                const double apq = a[p * k + q];
                if (apq == 0.0) continue;
                // negligible beside both diagonal entries: zeroed (Rutishauser's test), so
                // the sweeps end once the matrix is diagonal to working precision
                const double g = 100.0 * std::fabs(apq);
                if (std::fabs(a[p * k + p]) + g == std::fabs(a[p * k + p]) &&
                    std::fabs(a[q * k + q]) + g == std::fabs(a[q * k + q])) {
                    a[p * k + q] = 0.0;
                    a[q * k + p] = 0.0;
                    continue;
                }
                // the rotation that zeroes a[p, q] (Golub & Van Loan, sym.schur2)
                const double tau = (a[q * k + q] - a[p * k + p]) / (2.0 * apq);
                const double t = (tau >= 0.0 ? 1.0 : -1.0) / (std::fabs(tau) + std::sqrt(1.0 + tau * tau));
                const double c = 1.0 / std::sqrt(1.0 + t * t), s = t * c;
                for (int r = 0; r < k; ++r) {  // A <- A J
                    const double arp = a[r * k + p], arq = a[r * k + q];
                    a[r * k + p] = c * arp - s * arq;
                    a[r * k + q] = s * arp + c * arq;
                }
                for (int r = 0; r < k; ++r) {  // A <- J^T A
                    const double apr = a[p * k + r], aqr = a[q * k + r];
                    a[p * k + r] = c * apr - s * aqr;
                    a[q * k + r] = s * apr + c * aqr;
                }
                for (int r = 0; r < k; ++r) {  // V <- V J
                    const double vrp = vec[r * k + p], vrq = vec[r * k + q];
                    vec[r * k + p] = c * vrp - s * vrq;
                    vec[r * k + q] = s * vrp + c * vrq;
                }
            }
        }
    }
    // ascending, eigenvectors following their values
    std::vector<int> order(k);
    for (int i = 0; i < k; ++i) order[i] = i;
    std::stable_sort(order.begin(), order.end(),
                     [&a, k](int x, int y) { return a[x * k + x] < a[y * k + y]; });
    ev.assign(k, 0.0);
    std::vector<double> sorted(static_cast<size_t>(k) * k);
    for (int c = 0; c < k; ++c) {
        ev[c] = a[order[c] * k + order[c]];
        for (int r = 0; r < k; ++r) sorted[r * k + c] = vec[r * k + order[c]];
    }
    vec.swap(sorted);
}

void cramer_rao(const double* jraw, int n, int k, const double* grad, int nq, double sigma,
                std::vector<double>& std_out, double& cond) {
    std::vector<double> col(k);
    for (int j = 0; j < k; ++j) {
        double acc = 0.0;
        for (int r = 0; r < n; ++r) acc += jraw[r * k + j] * jraw[r * k + j];
        col[j] = std::sqrt(acc);
    }
    std_out.assign(nq, NaN);
    cond = INF;
    if (k == 0 || *std::min_element(col.begin(), col.end()) <= 0.0) return;
    // the normalised normal matrix Jn^T Jn, Jn = J / col
    std::vector<double> nn(static_cast<size_t>(k) * k);
    for (int i = 0; i < k; ++i)
        for (int j = 0; j < k; ++j) {
            double acc = 0.0;
            for (int r = 0; r < n; ++r) acc += (jraw[r * k + i] / col[i]) * (jraw[r * k + j] / col[j]);
            nn[i * k + j] = acc;
        }
    std::vector<double> ev, vec;
    symmetric_eigen(nn, k, ev, vec);
    if (ev[0] <= 0.0) return;
    cond = std::sqrt(ev[k - 1] / ev[0]);
    std::vector<double> cov(static_cast<size_t>(k) * k);
    for (int i = 0; i < k; ++i)
        for (int j = 0; j < k; ++j) {
            double acc = 0.0;
            for (int e = 0; e < k; ++e) acc += vec[i * k + e] / ev[e] * vec[j * k + e];
            cov[i * k + j] = acc * (sigma * sigma / (col[i] * col[j]));
        }
    for (int q = 0; q < nq; ++q) {
        const double* gq = grad + static_cast<size_t>(q) * k;
        double var = 0.0;
        for (int i = 0; i < k; ++i) {
            double row = 0.0;
            for (int j = 0; j < k; ++j) row += cov[i * k + j] * gq[j];
            var += gq[i] * row;
        }
        if (var >= 0.0) std_out[q] = std::sqrt(var);
    }
}

namespace {
std::vector<double> vec_of(const Arr& a) { return std::vector<double>(a.data(), a.data() + a.size()); }
}  // namespace

void bind_lsq(py::module_& m) {
    py::register_exception_translator([](std::exception_ptr p) {
        try {
            if (p) std::rethrow_exception(p);
        } catch (const SingularMatrix& e) {
            const py::object err = py::module_::import("numpy.linalg").attr("LinAlgError");
            PyErr_SetString(err.ptr(), e.what());
        }
    });
    m.def("normal_equations", [](Arr jac, Arr r) {
        const int k = static_cast<int>(dim(jac, 1)), n = static_cast<int>(dim(jac, 0));
        if (r.size() != n) throw py::value_error("normal_equations: r needs one entry per row of jac");
        std::vector<double> jtj, g, diag;
        normal_equations(jac.data(), r.data(), n, k, jtj, g, diag);
        return py::make_tuple(to_array(jtj, k, k), to_array(g), to_array(diag));
    });
    m.def("finite_cost", [](Arr r, Arr jac) {
        return finite_cost(r.data(), static_cast<int>(r.size()), jac.data(), static_cast<int>(jac.size()));
    });
    m.def("damped_step", [](Arr jtj, Arr g, Arr diag, double lam, Arr scale) {
        const int k = static_cast<int>(g.size());
        if (jtj.size() != static_cast<py::ssize_t>(k) * k || diag.size() != k || scale.size() != k)
            throw py::value_error("damped_step: jtj (k, k), g, diag and scale (k,) needed");
        std::vector<double> step;
        double over, predicted;
        if (!damped_step(vec_of(jtj), vec_of(g), vec_of(diag), lam, scale.data(), k, step, over, predicted))
            throw SingularMatrix();
        return py::make_tuple(to_array(step), over, predicted);
    });
    m.def("cramer_rao", [](Arr jraw, Arr grad, double sigma) {
        const int n = static_cast<int>(dim(jraw, 0)), k = static_cast<int>(dim(jraw, 1));
        const int nq = static_cast<int>(dim(grad, 0));
        if (dim(grad, 1) != k && nq > 0) throw py::value_error("cramer_rao: grad needs k columns");
        std::vector<double> std_out;
        double cond;
        cramer_rao(jraw.data(), n, k, grad.data(), nq, sigma, std_out, cond);
        return py::make_tuple(to_array(std_out), cond);
    });
}
}  // namespace tactiled
