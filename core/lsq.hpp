// The least-squares pieces of a Levenberg-Marquardt step and of the fit's uncertainty; Python
// reference: tactiled/physics/kernels.py (normal_equations, finite_cost, damped_step,
// cramer_rao).  Matrices are small (k <= 6 parameters), row-major, solved directly.
#pragma once
#include <stdexcept>
#include <vector>

namespace tactiled {

// A singular damped system (numpy.linalg.LinAlgError in Python, as np.linalg.solve raises).
struct SingularMatrix : std::runtime_error {
    SingularMatrix() : std::runtime_error("Singular matrix") {}
};

// J^T J (k x k), J^T r (k) and the Marquardt scaling diag(J^T J), floored at 1e-12 of its
// largest entry so a dead parameter still gets damped; jac is n x k.
void normal_equations(const double* jac, const double* r, int n, int k, std::vector<double>& jtj,
                      std::vector<double>& g, std::vector<double>& diag);

// sum(r^2), or inf if any residual or Jacobian entry is not finite.
double finite_cost(const double* r, int n, const double* jac, int jac_size);

// Solve a x = b (k x k, row-major) by LU with partial pivoting (LAPACK's dgesv: the largest
// pivot, the first on ties); false when a pivot is exactly zero (a singular matrix).
bool lu_solve(std::vector<double> a, std::vector<double> b, int k, std::vector<double>& x);

// (J^T J + lam diag) step = -J^T r, the step capped so no |step_i| exceeds scale_i; returns
// false when the matrix is singular.  `over` is max |step|/scale (1 when capped), `predicted`
// the cost decrease the linear model promises: -(2 g.s + s.JTJ.s).
bool damped_step(const std::vector<double>& jtj, const std::vector<double>& g,
                 const std::vector<double>& diag, double lam, const double* scale, int k,
                 std::vector<double>& step, double& over, double& predicted);

// Eigenvalues (ascending) and eigenvectors (columns of vec, k x k row-major) of a symmetric
// matrix, by cyclic Jacobi rotations (exact enough for k <= 6: to a few ulps of the largest).
void symmetric_eigen(std::vector<double> a, int k, std::vector<double>& ev, std::vector<double>& vec);

// 1-sigma bounds of the quantities whose gradients are grad's rows (nq x k), from
// cov = sigma^2 (J^T J)^-1 with J's columns scaled to unit norm first; and J's condition
// number (inf if singular: the bounds are then NaN).
void cramer_rao(const double* jraw, int n, int k, const double* grad, int nq, double sigma,
                std::vector<double>& std_out, double& cond);
}  // namespace tactiled
