// The half-space's weighted Green's sum (halfspace.hpp) and its binding.
#include "halfspace.hpp"

#include <cmath>

#include "arrays.hpp"
#include "stages.hpp"

namespace tactiled {

void green_weighted(const double* px, const double* py, std::int64_t npts, const double* ox,
                    const double* oy, std::int64_t nn, const double* weights, std::int64_t nk,
                    double z, double g, double nu, double* out) {
    const std::int64_t total = nk * 9 * npts;
    for (std::int64_t t = 0; t < total; ++t) out[t] = 0.0;
    const double k2 = 1.0 - 2.0 * nu;
    const double c = 1.0 / (4.0 * M_PI * g);
    const double zz = z * z;
    auto at = [&](std::int64_t k, int i, int j, std::int64_t p) -> double& {
        return out[((k * 3 + i) * 3 + j) * npts + p];
    };
    for (std::int64_t p = 0; p < npts; ++p)
        for (std::int64_t n = 0; n < nn; ++n) {
            const double dx = px[p] - ox[n];
            const double dy = py[p] - oy[n];
            const double rho2 = dx * dx + dy * dy + zz;
            const double rho = std::sqrt(rho2);
            const double inv_r = 1.0 / rho;
            const double inv_r3 = inv_r / rho2;
            const double rz = rho + z;
            const double a = inv_r / rz;
            const double b = a / rz;
            const double gxx = c * (inv_r + dx * dx * inv_r3 + k2 * (1.0 / rz - dx * dx * b));
            const double gyy = c * (inv_r + dy * dy * inv_r3 + k2 * (1.0 / rz - dy * dy * b));
            const double gxy = c * dx * dy * (inv_r3 - k2 * b);
            const double gzx = c * dx * (z * inv_r3 + k2 * a);
            const double gzy = c * dy * (z * inv_r3 + k2 * a);
            const double gxz = c * dx * (z * inv_r3 - k2 * a);
            const double gyz = c * dy * (z * inv_r3 - k2 * a);
            const double gzz = c * (zz * inv_r3 + 2.0 * (1.0 - nu) * inv_r);
            for (std::int64_t k = 0; k < nk; ++k) {
                const double* w = weights + k * 3 * nn;
                const double wx = w[n], wy = w[nn + n], wz = w[2 * nn + n];
                at(k, 0, 0, p) += gxx * wx;
                at(k, 1, 0, p) += gxy * wx;
                at(k, 2, 0, p) += gzx * wx;
                at(k, 0, 1, p) += gxy * wy;
                at(k, 1, 1, p) += gyy * wy;
                at(k, 2, 1, p) += gzy * wy;
                at(k, 0, 2, p) += gxz * wz;
                at(k, 1, 2, p) += gyz * wz;
                at(k, 2, 2, p) += gzz * wz;
            }
        }
}

void bind_halfspace(py::module_& m) {
    m.def(
        "green_weighted",
        [](Arr px, Arr py_, Arr ox, Arr oy, Arr weights, double z, double g, double nu) {
            const py::ssize_t npts = px.size(), nn = ox.size();
            if (py_.size() != npts || oy.size() != nn)
                throw py::value_error("px, py and ox, oy: one value per point and per node");
            if (weights.ndim() != 3 || weights.shape(1) != 3 || weights.shape(2) != nn)
                throw py::value_error("weights: expected shape (k, 3, nodes)");
            const py::ssize_t nk = weights.shape(0);
            py::array_t<double> out({nk, py::ssize_t{3}, py::ssize_t{3}, npts});
            green_weighted(px.data(), py_.data(), npts, ox.data(), oy.data(), nn, weights.data(),
                           nk, z, g, nu, out.mutable_data());
            return out;
        },
        "Displacements of k sets of point forces at the nodes "
        "(tactiled.physics.halfspace.green_weighted).");
}
}  // namespace tactiled
