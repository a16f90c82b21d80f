#pragma once
// Height-based objective terms (fabrication penalties and smoothness), local and exact.
//
// A local term gives a cost per vertex that reads heights within `radius()` of it. The
// objective holds the mean cost over the grid. Each vertex's weighted cost is quantised
// to an integer (2^-32 units) before summing, so a move's change, summed over the
// vertices it can affect, keeps the maintained total equal to a full recompute bit for
// bit. Costs should be O(1) per vertex.
//
// Plug a term of your own into the objective with any type that has
//     std::string_view name() const;  int radius() const;
//     double cost(const HeightsView& h, int i, int j) const;
// (see examples/custom_term.cpp).
#include <algorithm>
#include <cmath>
#include <concepts>
#include <cstdint>
#include <functional>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "../core/error.hpp"
#include "../core/math.hpp"
#include "../surface/overlay.hpp"
#include "../surface/tool.hpp"

namespace freeform {

// Heights of the surface as it is, or as a proposed move would leave it.
class HeightsView {
public:
    explicit HeightsView(const Heightmap& base, const HeightOverlay* overlay = nullptr)
        : base_(&base), overlay_(overlay) {}
    float operator()(int i, int j) const { return overlay_ ? overlay_->height(*base_, i, j) : (*base_)(i, j); }
    int nx() const { return base_->nx(); }
    int ny() const { return base_->ny(); }
    double du() const { return base_->du(); }
    double dv() const { return base_->dv(); }
    float h_min() const { return base_->h_min(); }
    float h_max() const { return base_->h_max(); }
    const Heightmap& base() const { return *base_; }

private:
    const Heightmap* base_;
    const HeightOverlay* overlay_;
};

template <class T>
concept LocalHeightTerm = requires(const T& t, const HeightsView& h, int i, int j) {
    { t.name() } -> std::convertible_to<std::string_view>;
    { t.radius() } -> std::convertible_to<int>;
    { t.cost(h, i, j) } -> std::convertible_to<double>;
};

// Keeps heights away from the hard fabrication bounds: zero in the middle of the range,
// rising quadratically to 1 over the outer `margin` fraction of the range at each end.
struct HeightBoundTerm {
    double margin = 0.05;
    std::string_view name() const { return "height_bound"; }
    int radius() const { return 0; }
    double cost(const HeightsView& h, int i, int j) const {
        const double range = double(h.h_max()) - h.h_min(), band = margin * range;
        if (!(band > 0)) return 0.0;
        const double v = h(i, j);
        const double over = std::max(0.0, v - (h.h_max() - band)) / band;
        const double under = std::max(0.0, (h.h_min() + band) - v) / band;
        return over * over + under * under;
    }
};

// Concave valleys sharper than the milling tool can cut: along each grid direction, the
// angle between the two segments meeting at a vertex where the surface bends up on both
// sides; the cost is the squared shortfall (radians) below `min_angle_deg`.
struct ValleyTerm {
    double min_angle_deg = 170.0;
    std::string_view name() const { return "concave_valley"; }
    int radius() const { return 1; }
    double cost(const HeightsView& h, int i, int j) const {
        const double limit = degrees_to_radians(min_angle_deg);
        double c = 0;
        auto along = [&](double hm, double h0, double hp, double step) {
            const double s1 = (h0 - hm) / step, s2 = (hp - h0) / step;
            if (s2 <= s1) return;  // convex or straight
            const double angle = pi - (std::atan(s2) - std::atan(s1));
            const double short_by = limit - angle;
            if (short_by > 0) c += short_by * short_by;
        };
        if (i > 0 && i + 1 < h.nx()) along(h(i - 1, j), h(i, j), h(i + 1, j), h.du());
        if (j > 0 && j + 1 < h.ny()) along(h(i, j - 1), h(i, j), h(i, j + 1), h.dv());
        return c;
    }
};

// A ball-end mill of radius `tool_radius` (metres) cannot cut a valley whose radius of
// curvature, seen from the front, is smaller: the cost is the squared shortfall of
// k_max * tool_radius above 1 (k_max the largest principal curvature at the vertex). It
// steers the annealer; cut_with_ball (surface/tool.hpp) makes the final surface obey.
struct ToolRadiusTerm {
    double tool_radius = 0.005;
    std::string_view name() const { return "tool_radius"; }
    int radius() const { return 1; }
    double cost(const HeightsView& h, int i, int j) const {
        if (i == 0 || j == 0 || i + 1 == h.nx() || j + 1 == h.ny()) return 0.0;
        const double over = vertex_curvature(h, i, j, h.du(), h.dv()).kappa_max * tool_radius - 1.0;
        return over > 0 ? over * over : 0.0;
    }
};

// Smoothness: the squared discrete Laplacian, relative to the height range.
struct SmoothnessTerm {
    std::string_view name() const { return "smoothness"; }
    int radius() const { return 1; }
    double cost(const HeightsView& h, int i, int j) const {
        if (i == 0 || j == 0 || i + 1 == h.nx() || j + 1 == h.ny()) return 0.0;
        const double range = double(h.h_max()) - h.h_min();
        const double lap = (double(h(i - 1, j)) + h(i + 1, j) + h(i, j - 1) + h(i, j + 1) - 4.0 * h(i, j)) / range;
        return lap * lap;
    }
};

// The weights of the built-in height terms (the scene file's "optimise" keys
// height_bound_weight, valley_weight, valley_min_angle, smoothness_weight); 0 leaves a
// term out. default_penalties (below) makes the terms from them.
struct PenaltyWeights {
    double height_bound = 0;
    double valley = 0;
    double valley_min_angle = 170;  // degrees (ValleyTerm::min_angle_deg)
    double smoothness = 0;
};

// The weighted local terms of an objective.
class Penalties {
public:
    static constexpr double quantum = 4294967296.0;  // 2^32 units per unit cost

    template <LocalHeightTerm T>
    void add(T term, double weight) {
        if (!(weight >= 0) || !std::isfinite(weight))
            throw InputError(std::string("objective.") + std::string(term.name()) + ": weight must be >= 0");
        if (weight == 0) return;
        terms_.push_back({std::string(term.name()), term.radius(), weight,
                          [term](const HeightsView& h, int i, int j) { return double(term.cost(h, i, j)); }});
        radius_ = std::max(radius_, term.radius());
    }
    bool empty() const { return terms_.empty(); }
    int radius() const { return radius_; }
    std::vector<std::string> names() const {
        std::vector<std::string> n;
        for (const auto& t : terms_) n.push_back(t.name);
        return n;
    }

    // Sum of quantised weighted costs over every vertex.
    std::int64_t full(const Heightmap& hm) const {
        if (terms_.empty()) return 0;
        const HeightsView h(hm);
        std::int64_t s = 0;
        for (int j = 0; j < hm.ny(); ++j)
            for (int i = 0; i < hm.nx(); ++i) s += vertex(h, i, j);
        return s;
    }

    // Change of full() if `o` were committed.
    std::int64_t delta(const Heightmap& hm, const HeightOverlay& o) const {
        if (terms_.empty() || o.empty()) return 0;
        const HeightsView before(hm), after(hm, &o);
        const Patch p = o.patch.dilated(radius_).clipped(hm.nx(), hm.ny());
        std::int64_t s = 0;
        for (int j = p.j0; j <= p.j1; ++j)
            for (int i = p.i0; i <= p.i1; ++i) s += vertex(after, i, j) - vertex(before, i, j);
        return s;
    }

    // Mean weighted cost per vertex, from a full() or maintained sum.
    static double value(std::int64_t sum, const Heightmap& hm) {
        return double(sum) / quantum / double(std::int64_t(hm.nx()) * hm.ny());
    }

private:
    struct Entry {
        std::string name;
        int radius;
        double weight;
        std::function<double(const HeightsView&, int, int)> cost;
    };
    std::int64_t vertex(const HeightsView& h, int i, int j) const {
        std::int64_t s = 0;
        for (const auto& t : terms_) s += std::llround(std::min(t.weight * t.cost(h, i, j), 1e6) * quantum);
        return s;
    }

    std::vector<Entry> terms_;
    int radius_ = 0;
};

// The weight of the tool-radius term when the surface has a tool_radius: a vertex whose
// concave curvature is twice what the tool can cut costs as much as an error of 1 in the
// mean over the grid divided by the vertex count, i.e. a few such vertices matter.
inline constexpr double tool_radius_weight = 1.0;

// The built-in terms `w` asks for, and the milling tool's when `tool_radius` > 0
// (surface.tool_radius); add terms of your own to it and pass it to design() (any type
// modelling LocalHeightTerm; docs/library.md "A custom term").
inline Penalties default_penalties(const PenaltyWeights& w, double tool_radius = 0) {
    Penalties p;
    p.add(HeightBoundTerm{}, w.height_bound);
    p.add(ValleyTerm{w.valley_min_angle}, w.valley);
    p.add(SmoothnessTerm{}, w.smoothness);
    if (tool_radius > 0) p.add(ToolRadiusTerm{tool_radius}, tool_radius_weight);
    return p;
}

}  // namespace freeform
