// The annealer knows nothing of optics: here it minimises the 10-D Rastrigin function,
// f(x) = Σ x_k² − 10 cos(2π x_k) + 10 on [−5.12, 5.12]^10 (global minimum 0 at the
// origin, a local minimum near every integer point).
#include <freeform/anneal.hpp>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>

namespace {

struct Rastrigin {
    struct Move {  // redraw one coordinate
        int k = 0;
        double value = 0;
    };
    std::array<double, 10> x{}, best{};
    double f = 0;

    static double term(double v) { return v * v - 10.0 * std::cos(6.283185307179586 * v) + 10.0; }
    void recompute() {
        f = 0;
        for (double v : x) f += term(v);
    }

    double energy() const { return f; }
    void propose(freeform::CounterRng& rng, double temperature, Move& m) const {
        m.k = static_cast<int>(rng.below(x.size()));
        // A Gaussian step that narrows as it cools: wide jumps between basins early on,
        // fine refinement at the end.
        const double sigma = std::clamp(1.5 * std::sqrt(temperature), 1e-3, 3.0);
        m.value = std::clamp(x[m.k] + sigma * rng.normal(), -5.12, 5.12);
    }
    double delta(const Move& m) const { return term(m.value) - term(x[m.k]); }
    void accept(const Move& m) {
        x[m.k] = m.value;
        recompute();
    }
    void reject(const Move&) {}
    void on_new_best() { best = x; }
    void restore_best() {  // called once at the end
        x = best;
        recompute();
    }
};

struct PrintProgress {
    void progress(const freeform::AnnealState& s) const {
        std::printf("%7lld iterations  T = %8.4f  energy = %9.5f  best = %9.5f  re-heats = %d\n",
                    static_cast<long long>(s.iteration), s.temperature, s.energy, s.best_energy, s.reheats);
    }
};

}  // namespace

int main() {
    Rastrigin problem;
    freeform::CounterRng start(2024);
    for (double& v : problem.x) v = start.uniform(-5.12, 5.12);
    problem.recompute();
    problem.best = problem.x;

    freeform::AnnealOptions options;
    options.seed = 1;
    options.initial_temperature = 10;
    options.cooling = 0.9;
    options.iterations_per_temperature = 500;
    options.patience = 12000;  // re-heat at half the previous start after this long without progress
    options.max_iterations = 100000;
    options.target_energy = 1e-4;
    options.progress_every = 10000;

    const freeform::AnnealResult r = freeform::anneal(problem, options, PrintProgress{});
    std::printf("stopped by %s after %lld iterations (%lld accepted) in %.3f s\n", freeform::to_string(r.reason),
                static_cast<long long>(r.iterations), static_cast<long long>(r.accepted), r.seconds);
    std::printf("best f = %.6g at x =", r.best_energy);
    for (double v : problem.x) std::printf(" %.4f", v);
    std::printf("\n");
    return r.best_energy < 1.0 ? 0 : 1;
}
