// Cold-start estimates: centre, force and the features the start table is searched by;
// Python reference: tactiled/fit/start.py (_force, _features, start_point, nearest,
// pick_separated, line_sum).
#pragma once
#include <vector>

namespace tactiled {

// sum_m h(m pitch - x0) over n tactels: the line response summed on the array (1/mm).
double line_sum(long long n, double pitch, double x0, double depth, double nu);

// Force (N) of a point load at (x0, y0) from the summed strain `total`:
// F = E total / (sum_m h_x sum_n h_y), clipped to [1e-3, 50].
double force_from_total(double total, double modulus, long long rows, double dx, double depth_x,
                        double nu_x, long long cols, double dy, double depth_y, double nu_y,
                        double x0, double y0);

// The 3x3 neighbourhood of the peak over the peak (NaN off the array) and log(peak / force).
void features(const double* strain, long long rows, long long cols, long long m, long long n,
              double force, double out[9]);

// The k rows of `table` (n x width) nearest feat (Euclidean), nearest first (ties: the lower
// index first); the squares summed in four lanes then the rest, as scipy's k-d tree sums them.
void nearest(const double* table, long long n, long long width, const double* feat, long long k,
             std::vector<double>& dist, std::vector<long long>& index);

// Indices into angles (deg, best first): the first, then each next whose orientation differs
// from every one chosen by min_separation (orientations modulo 180).
std::vector<long long> pick_separated(const double* angles, long long n, long long count,
                                      double min_separation);
}  // namespace tactiled
