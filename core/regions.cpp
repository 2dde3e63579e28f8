// Separate pressed regions (regions.hpp) and their binding.  The visiting order, the ranking
// of the regions a tactel joins and the final order are the Python reference's
// (tactiled/fit/regions.py watershed), ties included.
#include "regions.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>

#include "arrays.hpp"
#include "stages.hpp"

namespace tactiled {

std::vector<WaterRegion> watershed(const double* flat, std::int64_t rows, std::int64_t cols,
                                   double sigma, double support_z, double significant_z,
                                   double separation_z, double separation_share,
                                   double absorbed_share, std::vector<std::int64_t>& labels) {
    const std::int64_t size = rows * cols;
    const double support = support_z * sigma;
    const double significant = significant_z * sigma;
    auto separable = [&](double peak, double saddle, double share) {
        const double rise = peak - saddle;
        return peak > significant && rise > separation_z * sigma && rise > share * peak;
    };
    // tactels above the support, highest first, equal heights by index (a stable sort)
    std::vector<std::int64_t> order;
    for (std::int64_t i = 0; i < size; ++i)
        if (flat[i] > support) order.push_back(i);
    std::stable_sort(order.begin(), order.end(),
                     [&](std::int64_t a, std::int64_t b) { return -flat[a] < -flat[b]; });
    std::vector<std::int64_t> parent(static_cast<size_t>(size), -1);
    // regions by root tactel; `live` their roots in the order made, `done` regions of their own
    std::vector<WaterRegion> store;
    std::vector<std::int64_t> slot(static_cast<size_t>(size), -1);  // root -> index into store
    std::vector<std::int64_t> live, done;
    auto root = [&](std::int64_t i) {
        while (parent[i] != i) {
            parent[i] = parent[parent[i]];
            i = parent[i];
        }
        return i;
    };
    std::vector<std::int64_t> roots;
    for (const std::int64_t i : order) {
        const std::int64_t r = i / cols, c = i % cols;
        roots.clear();
        for (int dr = -1; dr <= 1; ++dr)
            for (int dc = -1; dc <= 1; ++dc) {
                const std::int64_t rr = r + dr, cc = c + dc;
                if ((dr || dc) && 0 <= rr && rr < rows && 0 <= cc && cc < cols) {
                    const std::int64_t j = rr * cols + cc;
                    if (parent[j] >= 0) {
                        const std::int64_t k = root(j);
                        if (std::find(roots.begin(), roots.end(), k) == roots.end()) roots.push_back(k);
                    }
                }
            }
        if (roots.empty()) {
            parent[i] = i;
            slot[i] = static_cast<std::int64_t>(store.size());
            store.push_back({i, flat[i], std::numeric_limits<double>::quiet_NaN(), {}, {i}});
            live.push_back(i);
            continue;
        }
        std::sort(roots.begin(), roots.end(), [&](std::int64_t a, std::int64_t b) {
            const double pa = store[slot[a]].peak, pb = store[slot[b]].peak;
            return -pa < -pb || (-pa == -pb && a < b);
        });
        const std::int64_t main = roots[0];
        const double level = flat[i];
        for (size_t q = 1; q < roots.size(); ++q) {
            const std::int64_t other = roots[q];
            live.erase(std::find(live.begin(), live.end(), other));
            parent[other] = main;
            WaterRegion& low = store[slot[other]];
            if (separable(low.peak, level, separation_share)) {
                low.saddle = level;
                done.push_back(other);
            } else {
                WaterRegion& high = store[slot[main]];
                high.members.insert(high.members.end(), low.members.begin(), low.members.end());
                high.absorbed.insert(high.absorbed.end(), low.absorbed.begin(), low.absorbed.end());
                if (separable(low.peak, level, absorbed_share))
                    high.absorbed.emplace_back(low.peak_idx, low.peak);
            }
        }
        parent[i] = main;
        store[slot[main]].members.push_back(i);
    }
    std::vector<WaterRegion> out;
    for (const auto* list : {&live, &done})
        for (const std::int64_t k : *list)
            if (store[slot[k]].peak > significant) out.push_back(std::move(store[slot[k]]));
    std::stable_sort(out.begin(), out.end(),
                     [](const WaterRegion& a, const WaterRegion& b) { return a.peak > b.peak; });
    labels.assign(static_cast<size_t>(size), -1);
    for (size_t k = 0; k < out.size(); ++k)
        for (const std::int64_t t : out[k].members) labels[t] = static_cast<std::int64_t>(k);
    return out;
}

void bind_regions(py::module_& m) {
    m.def(
        "watershed",
        [](Arr flat, long long rows, long long cols, double sigma, double support_z,
           double significant_z, double separation_z, double separation_share,
           double absorbed_share) {
            if (rows < 0 || cols < 0 || flat.ndim() != 1 || flat.size() != rows * cols)
                throw py::value_error("watershed: flat must hold rows * cols strains");
            std::vector<std::int64_t> labels;
            const auto regions = watershed(flat.data(), rows, cols, sigma, support_z, significant_z,
                                           separation_z, separation_share, absorbed_share, labels);
            const auto n = static_cast<py::ssize_t>(regions.size());
            py::array_t<long long> peaks(n), lab(static_cast<py::ssize_t>(labels.size()));
            py::array_t<double> heights(n), saddles(n);
            size_t n_abs = 0;
            for (py::ssize_t k = 0; k < n; ++k) {
                peaks.mutable_data()[k] = regions[k].peak_idx;
                heights.mutable_data()[k] = regions[k].peak;
                saddles.mutable_data()[k] = regions[k].saddle;
                n_abs += regions[k].absorbed.size();
            }
            for (size_t t = 0; t < labels.size(); ++t) lab.mutable_data()[t] = labels[t];
            py::array_t<double> absorbed({static_cast<py::ssize_t>(n_abs), py::ssize_t{3}});
            double* a = absorbed.mutable_data();
            for (py::ssize_t k = 0; k < n; ++k)
                for (const auto& [j, h] : regions[k].absorbed) {
                    *a++ = static_cast<double>(k);
                    *a++ = static_cast<double>(j);
                    *a++ = h;
                }
            return py::make_tuple(peaks, heights, saddles, lab, absorbed);
        },
        "Separate pressed regions by topographic prominence (tactiled.fit.regions.watershed).");
}
}  // namespace tactiled
