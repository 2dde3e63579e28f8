// The Levenberg-Marquardt search of one start, whole (Python reference: tactiled/fit/compiled.py,
// search / _evaluate / ellipse_at).  Each evaluation maps the model's parameters to the
// physics (models.hpp), solves the Hertz ellipse (hertz.hpp), sizes the quadrature rule by the
// node-count rule, and forms the window residual (quadrature.hpp) or, for the line model, the
// line residual (line.hpp); the damping loop is solver.levenberg_marquardt's, step for step.
#pragma once
#include <vector>

namespace tactiled {

// Status codes of an evaluation and of a search (compiled.py's _OK ... _BUDGET).
enum Status { OK = 0, INVALID_LINE = 1, INVALID_LONG = 2, FALLBACK = 3, BUDGET = 4 };
// The line model's kind (tactiled.fit.line): its own evaluation, the same search.
constexpr int LINE_KIND = 3;
// Nodes per axis at most (tactiled.physics.strain.MAX_NODES) and at least (MIN_NODES).
constexpr int MAX_NODES = 1024;
constexpr int MIN_NODES = 3;

// Work units of one evaluation (tactiled.fit.budget: EVALUATION_OVERHEAD, LARGE_RULE_NODES,
// LARGE_RULE_FACTOR; LINE_OVERHEAD, LINE_WORK_PER_NODE; a test holds them equal).
double evaluation_work(long long nodes_u, long long nodes_s, long long points);
double line_work(long long nodes, long long points);
// the tactels a line's band is charged at most (tactiled.fit.budget.LINE_CHARGED_TACTELS; a
// test holds the two equal)
constexpr long long LINE_CHARGED_TACTELS = 16;

// The model and the physics constants of a search.
struct ModelArgs {
    int kind, k;           // model kind (0 cylinder, 1 sphere, 2 general, 3 line), parameters
    double rf, comp;       // finger radius (mm), compliance (mm^2/N)
    double scale, dmin;    // 3/(2 pi E), the smaller rubber depth (mm)
    double tol;            // quadrature tolerance
    const double* imp;     // [d_x, nu_x, d_y, nu_y]
};

// A fit window: its grid, targets and weights (one per tactel, flattened row-major).
struct WindowArgs {
    const double *xs, *ys;
    int mx, ny;
    const double *target, *inv_scale, *ex, *ey;
    const bool* valid;
};

// The ladder of rule sizes and their packed Gauss rules (compiled.py's rule_tables).
struct Rules {
    const long long* ladder;
    int n_ladder;
    const long long* offsets;
    const double *ru, *rwu, *rs, *rws;
};

// strain.nodes_for: the ladder size for an extent (mm) under a depth (mm), or -1 beyond
// MAX_NODES (too long to integrate).
long long nodes_for(double extent, double depth, double tol, const Rules& rules);

struct Evaluation {
    int status;
    std::vector<double> r, jac;  // rows x k (one zero row when not evaluated)
    double work;
};

// One evaluation of the residual: status OK, INVALID_LINE (an infinite line contact),
// INVALID_LONG (too long to integrate, the semi-axis in r[0]), FALLBACK (a rule past
// max_nodes per axis) or BUDGET (its work exceeds work_left: not evaluated).
Evaluation evaluate(const double* p, const ModelArgs& model, const WindowArgs& win,
                    const Rules& rules, double work_left, long long max_nodes);

// The Hertz ellipse (a, b, theta, m) of model `kind` at p (a < 0: an infinite line).
void ellipse_at(int kind, const double* p, int k, double rf, double comp, double out[4]);

struct SearchResult {
    int status;
    std::vector<double> p, r, jac;
    double cost;
    int iterations, evaluations;
    bool converged;
    int message;        // index into compiled.MESSAGES; -1 invalid start, -2 non-finite start
    double remaining;   // solver.remaining_decrease at the end point
    double work;
};

// The search's tuning (solver.levenberg_marquardt's) and the budget it spends.
struct SearchArgs {
    const double* max_step;
    int max_iter;
    double xtol, ftol, lam0, atol;
    const double *lo, *hi;
    double work_left;
    long long max_nodes;
    double noise_cost, reserve, grant_cost;
    bool start_ok;
};

SearchResult search(const double* p0, const ModelArgs& model, const WindowArgs& win,
                    const Rules& rules, const SearchArgs& args);
}  // namespace tactiled
