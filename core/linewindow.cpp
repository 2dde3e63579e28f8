// The line model's band (linewindow.hpp) and its binding.
#include "linewindow.hpp"

#include <string>
#include <utility>
#include <vector>

#include "arrays.hpp"
#include "stages.hpp"

namespace tactiled {

void ridge_band(const double* clean, const bool* ok, std::int64_t rows, std::int64_t cols,
                std::int64_t m, std::int64_t n, double threshold, bool* out) {
    std::vector<char> ridge(static_cast<std::size_t>(rows * cols), 0);
    std::vector<std::pair<std::int64_t, std::int64_t>> stack;
    stack.reserve(static_cast<std::size_t>(rows * cols));
    ridge[m * cols + n] = 1;
    stack.emplace_back(m, n);
    while (!stack.empty()) {
        const auto [i, j] = stack.back();
        stack.pop_back();
        for (int di = -1; di <= 1; ++di)
            for (int dj = -1; dj <= 1; ++dj) {
                const std::int64_t a = i + di, b = j + dj;
                if (0 <= a && a < rows && 0 <= b && b < cols && !ridge[a * cols + b] &&
                    ok[a * cols + b] && clean[a * cols + b] > threshold) {
                    ridge[a * cols + b] = 1;
                    stack.emplace_back(a, b);
                }
            }
    }
    for (std::int64_t t = 0; t < rows * cols; ++t) out[t] = false;
    for (std::int64_t i = 0; i < rows; ++i)
        for (std::int64_t j = 0; j < cols; ++j) {
            if (!ridge[i * cols + j]) continue;
            for (int di = -1; di <= 1; ++di)
                for (int dj = -1; dj <= 1; ++dj) {
                    const std::int64_t a = i + di, b = j + dj;
                    if (0 <= a && a < rows && 0 <= b && b < cols && ok[a * cols + b])
                        out[a * cols + b] = true;
                }
        }
}

void bind_linewindow(py::module_& m) {
    m.def(
        "ridge_band",
        [](Arr clean, BArr ok, long long mm, long long n, double threshold) {
            long long rows, cols;
            frame_shape(clean, rows, cols);
            if (ok.ndim() != 2 || ok.shape(0) != rows || ok.shape(1) != cols)
                throw py::value_error("ok: expected the frame's shape");
            if (mm < 0 || mm >= rows || n < 0 || n >= cols)
                throw py::index_error("peak outside the frame");
            py::array_t<bool> out({static_cast<py::ssize_t>(rows), static_cast<py::ssize_t>(cols)});
            ridge_band(clean.data(), ok.data(), rows, cols, mm, n, threshold, out.mutable_data());
            return out;
        },
        "The line's band: a flood fill from the peak, grown by one tactel "
        "(tactiled.fit.linewindow.ridge_band).");
}
}  // namespace tactiled
