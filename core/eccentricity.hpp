// Eccentricity of a Hertz contact ellipse from its curvature ratio, scalar (MODEL.md; Python
// reference: tactiled/physics/eccentricity.py, ellip_ke / kernel_scalar / solve_log_scalar).
//
// lambda = A'/C' = (E/(1-m) - K) / (K - E) is solved for m at x = log(lambda - 1): a table of x
// against y = logit(m) gives a start, Newton steps on x(y) polish it.  The table and the power
// series' coefficients are the Python module's own numbers, handed over once at its import
// (set_eccentricity_tables), so both implementations start from the same doubles.
#pragma once
#include <vector>

namespace tactiled {

struct EccentricityTables {
    std::vector<double> xt;              // x = log(lambda - 1) at y = yt0 + i dy
    double yt0 = 0.0, dy = 0.0;
    double x_min = 0.0, x_max = 0.0;     // the table's ends: x is clamped to them
    double series_below = 0.05;          // m below which the power series replace the AGM
    std::vector<double> dm_h, pm_h, ddm_h, dpm_h;  // series coefficients, highest power first
};

// The tables (empty until tactiled.physics.eccentricity is imported).
EccentricityTables& eccentricity_tables();

// Complete elliptic integrals K(m), E(m) by the arithmetic-geometric mean; m1 = 1 - m given
// separately so near-line contacts keep full precision.
void ellip_ke(double m, double m1, double& k, double& e);

// Horner's rule, coefficients highest power first.
double horner(const std::vector<double>& coef_high_first, double m);

// (K-E)/m, (lambda-1)(K-E)/m and their m-derivatives.
void kernel_scalar(double m, double m1, double& dm, double& pm, double& ddm, double& dpm);

struct LogSolution {
    double m, m1, log_f, dlogf_dx, dlogm1_dx;
};

// m at x = log(lambda - 1): (m, m1, log((K-E)/m), d log_f/dx, d log m1/dx).
LogSolution solve_log_scalar(double x, int newton_steps);
}  // namespace tactiled
