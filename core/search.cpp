// The compiled Levenberg-Marquardt search (search.hpp) and its bindings.
#include "search.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

#include "arrays.hpp"
#include "hertz.hpp"
#include "line.hpp"
#include "lsq.hpp"
#include "models.hpp"
#include "pymath.hpp"
#include "quadrature.hpp"
#include "stages.hpp"

namespace tactiled {
namespace {
const double INF = std::numeric_limits<double>::infinity();

// np.searchsorted(ladder, n) (side "left")
int rule_index(long long n, const Rules& rules) {
    return static_cast<int>(std::lower_bound(rules.ladder, rules.ladder + rules.n_ladder, n) - rules.ladder);
}

// np.clip(x, lo, hi), element by element as min(max(x, lo), hi)
std::vector<double> clip(const std::vector<double>& x, const double* lo, const double* hi) {
    std::vector<double> out(x.size());
    for (size_t i = 0; i < x.size(); ++i) out[i] = py_min(py_max(x[i], lo[i]), hi[i]);
    return out;
}

// An evaluation that was not made: one zero row.
Evaluation none(int status, int k, double first = 0.0) {
    Evaluation e{status, std::vector<double>(1, 0.0), std::vector<double>(k, 0.0), 0.0};
    e.r[0] = first;
    return e;
}

// The line model's evaluation: the rule across the line its half-width needs, its work, then
// the line residual; the cover's modulus comes back from scale = 3/(2 pi E).
Evaluation evaluate_line(const double* p, const ModelArgs& md, const WindowArgs& win,
                         const Rules& rules, double work_left, long long max_nodes) {
    const double b = std::sqrt(4.0 * std::exp(p[2]) * std::exp(p[0]) * md.comp / M_PI);
    const long long n = nodes_for(b, md.dmin, md.tol, rules);
    const int points = win.mx * win.ny;
    if (n < 0) return none(INVALID_LONG, 4, b);
    // a band is charged its valid tactels, at most LINE_CHARGED_TACTELS (budget.py)
    long long valid = 0;
    for (int k = 0; k < points; ++k) valid += win.valid[k] ? 1 : 0;
    const double work = line_work(n, valid < LINE_CHARGED_TACTELS ? valid : LINE_CHARGED_TACTELS);
    if (work > work_left) return none(BUDGET, 4);
    if (n > max_nodes) return none(FALLBACK, 4);
    const long long o = rules.offsets[rule_index(n, rules)];
    std::vector<double> px, py;
    double ref_x, ref_y;
    line_points(win.xs, win.mx, win.ys, win.ny, win.ex, win.ey, px, py, ref_x, ref_y);
    Evaluation e{OK, {}, {}, work};
    line_residual(p, px.data(), py.data(), points, ref_x, ref_y, md.imp,
                  3.0 / (2.0 * M_PI * md.scale), md.comp, rules.rs + o, rules.rws + o,
                  static_cast<int>(n), win.target, win.valid, win.inv_scale, e.r, e.jac);
    return e;
}

// solver._pin: parameters on a bound that the descent pushes out are held (their rows and
// columns of J^T J and their gradient zeroed).
void pin(const std::vector<double>& p, std::vector<double>& jtj, std::vector<double>& g,
         const double* lo, const double* hi) {
    const int k = static_cast<int>(p.size());
    for (int i = 0; i < k; ++i) {
        if ((p[i] <= lo[i] && g[i] > 0.0) || (p[i] >= hi[i] && g[i] < 0.0)) {
            for (int j = 0; j < k; ++j) {
                jtj[i * k + j] = 0.0;
                jtj[j * k + i] = 0.0;
            }
            g[i] = 0.0;
        }
    }
}

// solver.remaining_decrease at p: the decrease a nearly undamped step promises.
double remaining(const std::vector<double>& jac, const std::vector<double>& r, const double* scale,
                 const std::vector<double>& p, const double* lo, const double* hi) {
    const int k = static_cast<int>(p.size());
    std::vector<double> jtj, g, diag, step;
    normal_equations(jac.data(), r.data(), static_cast<int>(r.size()), k, jtj, g, diag);
    pin(p, jtj, g, lo, hi);
    double over, predicted;
    if (!damped_step(jtj, g, diag, 1e-9, scale, k, step, over, predicted)) return INF;
    return std::isfinite(predicted) ? predicted : INF;
}
}  // namespace

double evaluation_work(long long nodes_u, long long nodes_s, long long points) {
    const long long nodes = nodes_u * nodes_s;
    return static_cast<double>(1000 + nodes * points * (nodes > 8192 ? 3 : 1));
}

double line_work(long long nodes, long long points) {
    return static_cast<double>(1000 + 36 * nodes * points);
}

long long nodes_for(double extent, double depth, double tol, const Rules& rules) {
    const double r = depth / py_max(extent, 1e-12);
    const double log_rho = std::asinh(r);
    const double n = log_rho > 0 ? std::ceil(0.5 * std::log(1.0 / tol) / log_rho) : MAX_NODES + 1;
    if (n > MAX_NODES) return -1;
    return rules.ladder[rule_index(static_cast<long long>(std::max(n, static_cast<double>(MIN_NODES))), rules)];
}

Evaluation evaluate(const double* p, const ModelArgs& md, const WindowArgs& win,
                    const Rules& rules, double work_left, long long max_nodes) {
    if (md.kind == LINE_KIND) return evaluate_line(p, md, win, rules, work_left, max_nodes);
    const int k = md.k;
    std::vector<double> d(static_cast<size_t>(6) * k, 0.0);
    const Physical ph = physical_map(md.kind, p, d.data(), k);
    double hj[12];
    const EllipseCore el = ellipse_core(ph.kappa_a, ph.kappa_b, ph.psi, ph.force, md.rf, md.comp, hj);
    if (el.a < 0.0) return none(INVALID_LINE, k);
    const long long nu = nodes_for(el.a, md.dmin, md.tol, rules);
    if (nu < 0) return none(INVALID_LONG, k, el.a);
    const long long ns = nodes_for(el.b, md.dmin, md.tol, rules);
    if (ns < 0) return none(INVALID_LONG, k, el.b);
    const int points = win.mx * win.ny;
    const double work = evaluation_work(nu, ns, points);
    if (work > work_left) return none(BUDGET, k);
    if (nu > max_nodes || ns > max_nodes) return none(FALLBACK, k);
    const long long ou = rules.offsets[rule_index(nu, rules)];
    const long long os = rules.offsets[rule_index(ns, rules)];
    // the unit-disk rule: Gauss-Jacobi(1, 1) in u times Gauss-Chebyshev-U across
    const int nq = static_cast<int>(nu * ns);
    std::vector<double> u(nq), v(nq), w(nq);
    for (long long i = 0; i < nu; ++i) {
        const double ui = rules.ru[ou + i], wui = rules.rwu[ou + i];
        const double root = std::sqrt(1.0 - ui * ui);
        for (long long j = 0; j < ns; ++j) {
            const long long q = i * ns + j;
            u[q] = ui;
            v[q] = root * rules.rs[os + j];
            w[q] = wui * rules.rws[os + j];
        }
    }
    const double geo[7] = {ph.x0, ph.y0, el.a, el.b, el.theta, ph.force, md.scale};
    Evaluation e{OK, {}, {}, work};
    window_residual(geo, hj, d.data(), k, u.data(), v.data(), w.data(), nq, win.xs, win.mx,
                    win.ys, win.ny, md.imp, win.target, win.valid, win.inv_scale, win.ex, win.ey,
                    e.r, e.jac);
    return e;
}

void ellipse_at(int kind, const double* p, int k, double rf, double comp, double out[4]) {
    std::vector<double> d(static_cast<size_t>(6) * k, 0.0);
    const Physical ph = physical_map(kind, p, d.data(), k);
    const EllipseCore el = ellipse_core(ph.kappa_a, ph.kappa_b, ph.psi, ph.force, rf, comp, nullptr);
    out[0] = el.a;
    out[1] = el.b;
    out[2] = el.theta;
    out[3] = el.m;
}

SearchResult search(const double* p0, const ModelArgs& md, const WindowArgs& win,
                    const Rules& rules, const SearchArgs& a) {
    const int k = md.k;
    std::vector<double> p = clip(std::vector<double>(p0, p0 + k), a.lo, a.hi);
    Evaluation ev = evaluate(p.data(), md, win, rules, a.work_left + (a.start_ok ? a.reserve : 0.0),
                             a.max_nodes);
    double work = ev.work;
    if (ev.status != OK) {
        const double extent = ev.status == INVALID_LONG ? ev.r[0] : 0.0;
        return {ev.status, p, ev.r, ev.jac, extent, 0, 1, false, -1, INF, work};
    }
    std::vector<double> r = std::move(ev.r), jac = std::move(ev.jac);
    double cost = finite_cost(r.data(), static_cast<int>(r.size()), jac.data(), static_cast<int>(jac.size()));
    if (!std::isfinite(cost))  // non-finite residual at start
        return {OK, p, r, jac, INF, 0, 1, false, -2, INF, work};
    double lam = a.lam0, nu = 2.0;
    int evals = 1, message = 0, it = 0;
    bool converged = false;
    std::vector<double> trial = p, r_new = r, jac_new = jac;
    double cost_new = cost;
    std::vector<double> jtj, g, diag, step;
    for (int iter = 1; iter <= a.max_iter; ++iter) {
        it = iter;
        normal_equations(jac.data(), r.data(), static_cast<int>(r.size()), k, jtj, g, diag);
        pin(p, jtj, g, a.lo, a.hi);
        bool accepted = false;
        while (lam < 1e12) {
            double over, predicted;
            if (!damped_step(jtj, g, diag, lam, a.max_step, k, step, over, predicted))
                throw SingularMatrix();
            if (over < a.xtol) {
                converged = true;
                message = 1;
                break;
            }
            if (predicted <= a.ftol * cost + a.atol * py_max(1.0, cost / a.noise_cost)) {
                converged = true;
                message = 2;
                break;
            }
            std::vector<double> moved(k);
            for (int i = 0; i < k; ++i) moved[i] = p[i] + step[i];
            trial = clip(moved, a.lo, a.hi);
            const double avail =
                a.work_left + ((cost <= a.grant_cost || work > a.work_left) ? a.reserve : 0.0);
            Evaluation tv = evaluate(trial.data(), md, win, rules, avail - work, a.max_nodes);
            if (tv.status == FALLBACK) return {FALLBACK, p, r, jac, cost, it, evals, false, 0, INF, work};
            if (tv.status == BUDGET) {
                message = 4;
                break;
            }
            work += tv.work;
            r_new = std::move(tv.r);
            jac_new = std::move(tv.jac);
            cost_new = tv.status == OK
                           ? finite_cost(r_new.data(), static_cast<int>(r_new.size()), jac_new.data(),
                                         static_cast<int>(jac_new.size()))
                           : INF;
            evals += 1;
            if (cost_new < INF) {
                if (cost_new < cost) {
                    const double rho = (cost - cost_new) / predicted;
                    lam = py_max(lam * py_max(1.0 / 3.0, 1.0 - std::pow(2.0 * rho - 1.0, 3.0)), 1e-12);
                    nu = 2.0;
                    accepted = true;
                    break;
                }
            }
            lam *= nu;
            nu *= 2.0;
        }
        if (converged || message == 4) break;
        if (!accepted) {
            message = 3;
            break;
        }
        p = trial;
        r = r_new;
        jac = jac_new;
        cost = cost_new;
    }
    const double rem = remaining(jac, r, a.max_step, p, a.lo, a.hi);
    return {OK, p, r, jac, cost, it, evals, converged, message, rem, work};
}

namespace {
// The rows of a residual vector r over k parameters, as numpy shapes them.
py::tuple evaluation_tuple(const Evaluation& e, int k) {
    const auto rows = static_cast<py::ssize_t>(e.r.size());
    return py::make_tuple(e.status, to_array(e.r), to_array(e.jac, rows, k), e.work);
}

WindowArgs window_of(const Arr& xs, const Arr& ys, const Arr& target, const BArr& valid,
                     const Arr& inv_scale, const Arr& ex, const Arr& ey) {
    const py::ssize_t cells = xs.size() * ys.size();
    if (target.size() != cells || valid.size() != cells || inv_scale.size() != cells ||
        ex.size() != cells || ey.size() != cells)
        throw py::value_error("window arrays must hold one entry per tactel of xs x ys");
    return {xs.data(), ys.data(), static_cast<int>(xs.size()), static_cast<int>(ys.size()),
            target.data(), inv_scale.data(), ex.data(), ey.data(), valid.data()};
}

Rules rules_of(const IArr& ladder, const IArr& offsets, const Arr& ru, const Arr& rwu,
               const Arr& rs, const Arr& rws) {
    return {ladder.data(), static_cast<int>(ladder.size()), offsets.data(), ru.data(), rwu.data(),
            rs.data(), rws.data()};
}

int model_size(int kind, const Arr& p) {
    const int need = kind == 0 ? 5 : kind == 1 ? 4 : kind == 2 ? 6 : kind == LINE_KIND ? 4 : -1;
    if (need < 0 || p.size() != need) throw py::value_error("p does not fit the model kind");
    return need;
}
}  // namespace

void bind_search(py::module_& m) {
    m.def("evaluation_work", &evaluation_work);
    m.def("line_work", &line_work);
    m.attr("LINE_CHARGED_TACTELS") = LINE_CHARGED_TACTELS;
    m.def("evaluate",
          [](int kind, Arr p, int k, double rf, double comp, double scale, double dmin, double tol,
             Arr imp, Arr xs, Arr ys, Arr target, BArr valid, Arr inv_scale, Arr ex, Arr ey,
             IArr ladder, IArr offsets, Arr ru, Arr rwu, Arr rs, Arr rws, double work_left,
             long long max_nodes) {
              const int kk = model_size(kind, p);
              (void)k;
              const ModelArgs md{kind, kk, rf, comp, scale, dmin, tol, imp.data()};
              const Evaluation e = evaluate(p.data(), md, window_of(xs, ys, target, valid, inv_scale, ex, ey),
                                            rules_of(ladder, offsets, ru, rwu, rs, rws), work_left,
                                            max_nodes);
              return evaluation_tuple(e, kind == LINE_KIND ? 4 : kk);
          },
          "tactiled.fit.compiled._evaluate: (status, r, J, work).");
    m.def("ellipse_at", [](int kind, Arr p, double rf, double comp) {
        double out[4];
        ellipse_at(kind, p.data(), model_size(kind, p), rf, comp, out);
        return py::make_tuple(out[0], out[1], out[2], out[3]);
    });
    m.def("search",
          [](int kind, Arr p0, Arr max_step, int max_iter, double xtol, double ftol, double lam0,
             double atol, Arr lo, Arr hi, double rf, double comp, double scale, double dmin,
             double tol, Arr imp, Arr xs, Arr ys, Arr target, BArr valid, Arr inv_scale, Arr ex,
             Arr ey, IArr ladder, IArr offsets, Arr ru, Arr rwu, Arr rs, Arr rws, double work_left,
             long long max_nodes, double noise_cost, double reserve, double grant_cost,
             bool start_ok) {
              const int k = model_size(kind, p0);
              if (max_step.size() != k || lo.size() != k || hi.size() != k)
                  throw py::value_error("search: max_step, lo and hi need one entry per parameter");
              const ModelArgs md{kind, k, rf, comp, scale, dmin, tol, imp.data()};
              const SearchArgs sa{max_step.data(), max_iter, xtol, ftol, lam0, atol, lo.data(),
                                  hi.data(), work_left, max_nodes, noise_cost, reserve,
                                  grant_cost, start_ok};
              const WindowArgs win = window_of(xs, ys, target, valid, inv_scale, ex, ey);
              const Rules rules = rules_of(ladder, offsets, ru, rwu, rs, rws);
              SearchResult s;
              {
                  py::gil_scoped_release nogil;  // the arrays stay referenced by this call
                  s = search(p0.data(), md, win, rules, sa);
              }
              const auto rows = static_cast<py::ssize_t>(s.r.size());
              return py::make_tuple(s.status, to_array(s.p), to_array(s.r), to_array(s.jac, rows, k),
                                    s.cost, s.iterations, s.evaluations, s.converged, s.message,
                                    s.remaining, s.work);
          },
          "tactiled.fit.compiled.search: one start's Levenberg-Marquardt search, whole.");
}
}  // namespace tactiled
