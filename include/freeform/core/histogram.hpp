#pragma once
// A receiver-sized grid of fixed-point irradiance (row 0 = top row of the image).
#include <cstdint>
#include <vector>

#include <Eigen/Core>

#include "fixed_point.hpp"
#include "view.hpp"

namespace freeform {

// Row-major float/double images; rows = height, cols = width, row 0 at the top.
using ImageF = Eigen::Array<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
using ImageD = Eigen::Array<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;

struct Histogram {
    int width = 0;
    int height = 0;
    std::vector<Fixed> cells;

    Histogram() = default;
    Histogram(int w, int h) : width(w), height(h), cells(std::size_t(w) * h, 0) {}

    void clear() { std::fill(cells.begin(), cells.end(), Fixed{0}); }
    Fixed total() const {
        Fixed s = 0;
        for (Fixed c : cells) s += c;
        return s;
    }
    View2D<Fixed> view() { return {cells.data(), width, height}; }
    View2D<const Fixed> view() const { return {cells.data(), width, height}; }
    bool operator==(const Histogram&) const = default;

    // Irradiance in units of mean ray weight per cell.
    ImageD to_image() const {
        ImageD img(height, width);
        for (int y = 0; y < height; ++y)
            for (int x = 0; x < width; ++x) img(y, x) = from_fixed(cells[std::size_t(y) * width + x]);
        return img;
    }
};

}  // namespace freeform
