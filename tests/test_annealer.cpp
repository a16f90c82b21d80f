// The generic annealer on problems that have nothing to do with optics: Rastrigin
// reaches its global basin, runs are the same for every speculative window and thread
// count, the stop rules, re-heat and sync points happen exactly where they should.
#include <doctest/doctest.h>

#include <freeform/anneal.hpp>

#include <algorithm>
#include <array>
#include <atomic>
#include <bit>
#include <cmath>
#include <cstdint>
#include <memory>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

using freeform::AnnealExchange;
using freeform::GeometricSchedule;
using freeform::validate_anneal_options;
using freeform::AnnealOptions;
using freeform::AnnealResult;
using freeform::AnnealState;
using freeform::BatchStats;
using freeform::CounterRng;
using freeform::InputError;
using freeform::StopReason;

namespace {

// One accepted move as the problem saw it: the iteration it came from is the number of
// moves judged before it.
struct AcceptedMove {
    std::int64_t iteration = 0;
    int coordinate = 0;
    double value = 0;
    double energy = 0;
    bool operator==(const AcceptedMove&) const = default;
};

// Rastrigin in 10-D: f(x) = Σ x² − 10 cos(2πx) + 10 over [−5.12, 5.12]^10, minimum 0 at
// the origin, a local minimum near every integer point. A move redraws one coordinate
// with a Gaussian step whose width follows the temperature.
struct Rastrigin {
    static constexpr int dims = 10;
    static constexpr double bound = 5.12;

    struct Move {
        int coordinate = 0;
        double value = 0;
    };

    std::array<double, dims> x{};
    std::array<double, dims> best_x{};
    double f = 0;
    double step_scale = 1.5;

    std::int64_t judged = 0;  // accept + reject calls
    std::vector<AcceptedMove> accepted;
    int restores = 0;

    explicit Rastrigin(std::uint64_t start) {
        CounterRng rng(start, 12345);
        for (double& v : x) v = rng.uniform(-bound, bound);
        f = total();
        best_x = x;
    }

    static double term(double v) { return v * v - 10.0 * std::cos(6.283185307179586 * v) + 10.0; }
    double total() const {
        double s = 0;
        for (double v : x) s += term(v);
        return s;
    }

    double energy() const { return f; }
    void propose(CounterRng& rng, double temperature, Move& m) const {
        m.coordinate = static_cast<int>(rng.below(dims));
        const double sigma = std::clamp(step_scale * std::sqrt(temperature), 1e-3, 3.0);
        m.value = std::clamp(x[m.coordinate] + sigma * rng.normal(), -bound, bound);
    }
    double delta(const Move& m) const { return term(m.value) - term(x[m.coordinate]); }
    void accept(const Move& m) {
        x[m.coordinate] = m.value;
        f = total();
        accepted.push_back({judged++, m.coordinate, m.value, f});
    }
    void reject(const Move&) { ++judged; }
    void on_new_best() { best_x = x; }
    void restore_best() {
        x = best_x;
        f = total();
        ++restores;
    }
};

// Rastrigin whose step width adapts at sync points from the acceptance rate since the
// previous one, as a bandit would: feedback comes through accept/reject and is folded
// into the proposal policy only in sync().
struct AdaptiveRastrigin : Rastrigin {
    using Rastrigin::Rastrigin;
    std::int64_t window_accepts = 0;
    std::int64_t window_judged = 0;
    int syncs = 0;

    void accept(const Move& m) {
        Rastrigin::accept(m);
        ++window_accepts;
        ++window_judged;
    }
    void reject(const Move& m) {
        Rastrigin::reject(m);
        ++window_judged;
    }
    int sync_interval() const { return 37; }
    void sync() {
        const double rate = double(window_accepts) / double(window_judged);
        step_scale = std::clamp(step_scale * (rate < 0.3 ? 0.9 : 1.1), 0.05, 2.0);
        window_accepts = window_judged = 0;
        ++syncs;
    }
};

// Energy 0 for ever: every move has delta 0, so every move is accepted and none is a new
// best. Records the temperature each judged move ran at.
struct FlatProblem {
    struct Move {
        double temperature = 0;
    };
    std::vector<double> temperatures;
    double energy() const { return 0.0; }
    void propose(CounterRng&, double temperature, Move& m) const { m.temperature = temperature; }
    double delta(const Move&) const { return 0.0; }
    void accept(const Move& m) { temperatures.push_back(m.temperature); }
    void reject(const Move& m) { temperatures.push_back(m.temperature); }
};

// Counts the moves judged between sync points; about half the moves are accepted.
struct SyncCounter {
    struct Move {
        double d = 0;
    };
    std::int64_t since_sync = 0;
    std::int64_t accepted = 0;
    std::vector<std::int64_t> gaps;
    double e = 100;
    double energy() const { return e; }
    void propose(CounterRng& rng, double, Move& m) const { m.d = rng.uniform(-1.0, 1.0); }
    double delta(const Move& m) const { return m.d; }
    void accept(const Move& m) {
        e += m.d;
        ++since_sync;
        ++accepted;
    }
    void reject(const Move&) { ++since_sync; }
    int sync_interval() const { return 10; }
    void sync() {
        gaps.push_back(since_sync);
        since_sync = 0;
    }
};

// Throws from the delta of its third proposal; counts the deltas computed.
struct ThrowingProblem {
    struct Move {
        int id = 0;
    };
    int proposed = 0;
    std::shared_ptr<std::atomic<int>> deltas = std::make_shared<std::atomic<int>>(0);
    double energy() const { return 1.0; }
    void propose(CounterRng&, double, Move& m) { m.id = proposed++; }
    double delta(const Move& m) const {
        ++*deltas;
        if (m.id == 2) throw std::runtime_error("delta failed");
        return 1.0;
    }
    void accept(const Move&) {}
    void reject(const Move&) {}
};

struct NoDelta {
    struct Move {};
    double energy() const { return 0; }
    void propose(CounterRng&, double, Move&) {}
    void accept(const Move&) {}
    void reject(const Move&) {}
};

static_assert(freeform::AnnealProblem<Rastrigin>);
static_assert(freeform::AnnealProblem<AdaptiveRastrigin>);
static_assert(freeform::AnnealProblem<FlatProblem>);
static_assert(!freeform::AnnealProblem<NoDelta>);
static_assert(!freeform::AnnealProblem<int>);

// Records every new best and the batch statistics.
struct Recorder {
    std::vector<AnnealState> bests;
    std::vector<BatchStats> batches;
    std::vector<AnnealState> progress_states;
    void new_best(const AnnealState& s) { bests.push_back(s); }
    void batch(const BatchStats& b) { batches.push_back(b); }
    void progress(const AnnealState& s) { progress_states.push_back(s); }
};

AnnealOptions rastrigin_options(std::uint64_t seed) {
    AnnealOptions o;
    o.seed = seed;
    o.initial_temperature = 10.0;
    o.cooling = 0.9;
    o.iterations_per_temperature = 500;
    o.patience = 12000;
    o.reheat_factor = 0.5;
    o.max_iterations = 60000;
    return o;
}

bool same_bits(const std::array<double, Rastrigin::dims>& a, const std::array<double, Rastrigin::dims>& b) {
    for (int k = 0; k < Rastrigin::dims; ++k)
        if (std::bit_cast<std::uint64_t>(a[k]) != std::bit_cast<std::uint64_t>(b[k])) return false;
    return true;
}

}  // namespace

TEST_CASE("Rastrigin 10-D reaches the global basin") {
    for (std::uint64_t seed : {1u, 2u, 3u}) {
        CAPTURE(seed);
        Rastrigin problem(seed * 101);
        const double start = problem.energy();
        const AnnealResult r = freeform::anneal(problem, rastrigin_options(seed));
        CHECK(r.reason == StopReason::max_iterations);
        CHECK(r.iterations == 60000);
        CHECK(r.best_energy < start);
        // restore_best() ran: the problem holds its best state.
        CHECK(problem.restores == 1);
        CHECK(problem.energy() == r.best_energy);
        CHECK(problem.energy() == doctest::Approx(problem.total()));
        CHECK(r.best_energy < 1.0);
        for (double v : problem.x) CHECK(std::abs(v) < 0.5);
        CHECK(r.accepted == std::int64_t(problem.accepted.size()));
        CHECK(r.proposals_evaluated == r.iterations);
    }
}

namespace {

template <class Problem>
struct Run {
    Problem problem;
    AnnealResult result;
    Recorder recorder;
};

// A run with re-heats, sync points (for AdaptiveRastrigin), progress reports and a stall
// rule, so that speculative windows are cut at every kind of point.
template <class Problem>
Run<Problem> trajectory_run(Problem problem, int speculative, int threads, std::int64_t iterations,
                            bool adaptive = false) {
    AnnealOptions o = rastrigin_options(7);
    o.adaptive_speculation = adaptive;
    o.max_iterations = iterations;
    o.iterations_per_temperature = 97;
    o.patience = 400;
    o.progress_every = 500;
    o.stall_iterations = 5000;
    o.speculative = speculative;
    o.threads = threads;
    Run<Problem> run{std::move(problem), {}, {}};
    run.result = freeform::anneal(run.problem, o, run.recorder);
    return run;
}

template <class Problem>
void check_same_trajectory(const Run<Problem>& a, const Run<Problem>& b) {
    CHECK(a.problem.accepted == b.problem.accepted);  // every accepted iteration, move and energy
    CHECK(a.problem.judged == b.problem.judged);
    CHECK(same_bits(a.problem.x, b.problem.x));
    CHECK(a.problem.step_scale == b.problem.step_scale);
    CHECK(a.result.best_energy == b.result.best_energy);
    CHECK(a.result.final_energy == b.result.final_energy);
    CHECK(a.result.iterations == b.result.iterations);
    CHECK(a.result.accepted == b.result.accepted);
    CHECK(a.result.reheats == b.result.reheats);
    CHECK(a.result.reason == b.result.reason);
    REQUIRE(a.recorder.bests.size() == b.recorder.bests.size());
    for (std::size_t k = 0; k < a.recorder.bests.size(); ++k) {
        CHECK(a.recorder.bests[k].iteration == b.recorder.bests[k].iteration);
        CHECK(a.recorder.bests[k].best_energy == b.recorder.bests[k].best_energy);
        CHECK(a.recorder.bests[k].temperature == b.recorder.bests[k].temperature);
    }
    REQUIRE(a.recorder.progress_states.size() == b.recorder.progress_states.size());
    for (std::size_t k = 0; k < a.recorder.progress_states.size(); ++k) {
        CHECK(a.recorder.progress_states[k].iteration == b.recorder.progress_states[k].iteration);
        CHECK(a.recorder.progress_states[k].energy == b.recorder.progress_states[k].energy);
        CHECK(a.recorder.progress_states[k].temperature == b.recorder.progress_states[k].temperature);
    }
    REQUIRE(a.recorder.batches.size() == b.recorder.batches.size());
    for (std::size_t k = 0; k < a.recorder.batches.size(); ++k) {
        CHECK(a.recorder.batches[k].iteration == b.recorder.batches[k].iteration);
        CHECK(a.recorder.batches[k].accepted == b.recorder.batches[k].accepted);
        CHECK(a.recorder.batches[k].mean_accepted_delta == b.recorder.batches[k].mean_accepted_delta);
    }
    // Speculation does extra work that is dropped, never less than the serial run.
    CHECK(b.result.proposals_evaluated >= b.result.iterations);
}

template <class Problem>
void check_thread_and_window_independence(const Problem& start) {
    const auto serial = trajectory_run(start, 1, 1, 6000);
    REQUIRE(serial.result.accepted > 100);
    REQUIRE(serial.result.reheats > 0);
    CHECK(serial.result.proposals_evaluated == serial.result.iterations);
    for (int speculative : {1, 2, 4, 7}) {
        CAPTURE(speculative);
        const auto run = trajectory_run(start, speculative, 1, 6000);
        check_same_trajectory(serial, run);
        if (speculative > 1) CHECK(run.result.proposals_evaluated > run.result.iterations);
    }
    // Threads only decide where the deltas of a window are evaluated. Shorter runs: a
    // parallel region per window is slow on a loaded machine when deltas are this cheap.
    const auto short_serial = trajectory_run(start, 1, 1, 600);
    for (int speculative : {3, 7}) {
        CAPTURE(speculative);
        check_same_trajectory(short_serial, trajectory_run(start, speculative, 2, 600));
    }
    // Adaptive runs switch between serial and speculative windows as they measure
    // which is faster; the trajectory must not notice.
    check_same_trajectory(serial, trajectory_run(start, 4, 2, 6000, true));
}

}  // namespace

TEST_CASE("the trajectory is the same for every speculative window and thread count") {
    SUBCASE("plain problem") { check_thread_and_window_independence(Rastrigin(3)); }
    SUBCASE("problem whose proposals adapt at sync points") {
        check_thread_and_window_independence(AdaptiveRastrigin(5));
        const auto run = trajectory_run(AdaptiveRastrigin(5), 4, 1, 6000);
        CHECK(run.problem.syncs == 6000 / 37);
        CHECK(run.recorder.batches.size() == std::size_t(6000 / 37));
    }
    SUBCASE("the seed changes the run") {
        const auto a = trajectory_run(Rastrigin(3), 1, 1, 6000);
        AnnealOptions o = rastrigin_options(8);
        o.max_iterations = 6000;
        Rastrigin other(3);
        freeform::anneal(other, o);
        CHECK(other.accepted != a.problem.accepted);
    }
}

namespace {

// A problem whose delta() must not run twice at once (as the Embree backend's, which
// shows a move to shared state to evaluate it): it counts the deltas in flight and
// records the most it ever saw. Each delta waits a little, so that two running at
// once would overlap.
struct OneAtATime : Rastrigin {
    static constexpr bool concurrent_deltas = false;
    std::shared_ptr<std::atomic<int>> in_flight = std::make_shared<std::atomic<int>>(0);
    std::shared_ptr<std::atomic<int>> most = std::make_shared<std::atomic<int>>(0);
    explicit OneAtATime(std::uint64_t start) : Rastrigin(start) {}
    double delta(const Move& m) const {
        const int now = ++*in_flight;
        int seen = most->load();
        while (now > seen && !most->compare_exchange_weak(seen, now)) {
        }
        volatile double spin = 0;
        for (int k = 0; k < 2000; ++k) spin = spin + std::sqrt(double(k));
        --*in_flight;
        return Rastrigin::delta(m);
    }
};

struct Overlapping : OneAtATime {
    static constexpr bool concurrent_deltas = true;
    using OneAtATime::OneAtATime;
};

}  // namespace

TEST_CASE("a problem that cannot evaluate deltas concurrently gets them one at a time, same trajectory") {
    static_assert(!freeform::anneal_detail::concurrent_deltas_of<OneAtATime>());
    static_assert(freeform::anneal_detail::concurrent_deltas_of<Rastrigin>());
    const auto serial = trajectory_run(OneAtATime(3), 1, 1, 3000);
    const auto windows = trajectory_run(OneAtATime(3), 4, 2, 3000);
    check_same_trajectory(serial, windows);
    CHECK(windows.result.proposals_evaluated > windows.result.iterations);  // speculation ran
    CHECK(*windows.problem.most == 1);
    // The same problem allowed to overlap does (the check above could fail).
    const auto parallel = trajectory_run(Overlapping(3), 4, 2, 3000);
    MESSAGE("most deltas in flight at once, concurrent problem: ", parallel.problem.most->load());
}

TEST_CASE("max_iterations stops exactly") {
    for (int speculative : {1, 7}) {
        AnnealOptions o = rastrigin_options(1);
        o.max_iterations = 12345;
        o.speculative = speculative;
        o.threads = 1;
        Rastrigin p(4);
        const AnnealResult r = freeform::anneal(p, o);
        CHECK(r.reason == StopReason::max_iterations);
        CHECK(r.iterations == 12345);
        CHECK(p.judged == 12345);
    }
}

TEST_CASE("target_energy stops at the first iteration that reaches it") {
    AnnealOptions o = rastrigin_options(2);
    o.max_iterations = 1000000;
    o.target_energy = 20.0;
    o.speculative = 3;
    o.threads = 1;
    Rastrigin p(9);
    REQUIRE(p.energy() > 20.0);
    Recorder rec;
    const AnnealResult r = freeform::anneal(p, o, rec);
    CHECK(r.reason == StopReason::target_energy);
    CHECK(r.best_energy <= 20.0);
    REQUIRE(!rec.bests.empty());
    CHECK(rec.bests.back().iteration == r.iterations);
    CHECK(rec.bests.back().best_energy <= 20.0);
    for (std::size_t k = 0; k + 1 < rec.bests.size(); ++k) CHECK(rec.bests[k].best_energy > 20.0);

    SUBCASE("a negative or NaN target is off") {
        for (double target : {-1.0, std::nan("")}) {
            AnnealOptions off = o;
            off.target_energy = target;
            off.max_iterations = 5000;
            Rastrigin q(9);
            CHECK(freeform::anneal(q, off).reason == StopReason::max_iterations);
        }
    }
}

TEST_CASE("a callback returning true stops the run at that point") {
    SUBCASE("progress") {
        struct StopAt300 {
            std::vector<std::int64_t> seen;
            bool progress(const AnnealState& s) {
                seen.push_back(s.iteration);
                return s.iteration >= 300;
            }
        } stopper;
        AnnealOptions o = rastrigin_options(1);
        o.progress_every = 100;
        o.speculative = 4;
        o.threads = 1;
        Rastrigin p(1);
        const AnnealResult r = freeform::anneal(p, o, stopper);
        CHECK(r.reason == StopReason::callback);
        CHECK(r.iterations == 300);
        // Reported at 100, 200, 300 and not again at the end (already reported there).
        CHECK(stopper.seen == std::vector<std::int64_t>{100, 200, 300});
    }
    SUBCASE("new_best") {
        struct ThirdBest {
            int count = 0;
            std::int64_t at = -1;
            bool new_best(const AnnealState& s) {
                if (++count == 3) at = s.iteration;
                return count == 3;
            }
        } stopper;
        Rastrigin p(1);
        const AnnealResult r = freeform::anneal(p, rastrigin_options(1), stopper);
        CHECK(r.reason == StopReason::callback);
        CHECK(stopper.count == 3);
        CHECK(r.iterations == stopper.at);
    }
    SUBCASE("begin") {
        struct Never {
            bool begin(const AnnealState&) { return true; }
        };
        Rastrigin p(1);
        const AnnealResult r = freeform::anneal(p, rastrigin_options(1), Never{});
        CHECK(r.reason == StopReason::callback);
        CHECK(r.iterations == 0);
        CHECK(r.proposals_evaluated == 0);
    }
    SUBCASE("callbacks are called in order, all of them, with the end hooks last") {
        struct Logger {
            std::vector<std::string>* log;
            const char* name;
            void begin(const AnnealState&) { log->push_back(std::string(name) + ":begin"); }
            bool progress(const AnnealState& s) {
                log->push_back(std::string(name) + ":progress " + std::to_string(s.iteration));
                return name[0] == 'A' && s.iteration == 20;
            }
            void end(const AnnealState& s) {
                log->push_back(std::string(name) + ":end " + std::to_string(s.iteration));
            }
        };
        std::vector<std::string> log;
        AnnealOptions o = rastrigin_options(1);
        o.progress_every = 10;
        Rastrigin p(1);
        const AnnealResult r = freeform::anneal(p, o, Logger{&log, "A"}, Logger{&log, "B"});
        CHECK(r.iterations == 20);
        CHECK(log == std::vector<std::string>{"A:begin", "B:begin", "A:progress 10", "B:progress 10", "A:progress 20",
                                              "B:progress 20", "A:end 20", "B:end 20"});
    }
}

TEST_CASE("stall_iterations stops after that many iterations without a new best") {
    for (int speculative : {1, 4}) {
        AnnealOptions o;
        o.stall_iterations = 50;
        o.speculative = speculative;
        o.threads = 1;
        FlatProblem p;
        const AnnealResult r = freeform::anneal(p, o);
        CHECK(r.reason == StopReason::stall);
        CHECK(r.iterations == 50);
        CHECK(p.temperatures.size() == 50);
    }
}

TEST_CASE("time_budget stops the run") {
    AnnealOptions o = rastrigin_options(1);
    o.max_iterations = 0;
    o.patience = 0;
    o.time_budget = 1e-3;
    Rastrigin p(1);
    const AnnealResult r = freeform::anneal(p, o);
    CHECK(r.reason == StopReason::time_budget);
    CHECK(r.iterations > 0);

    SUBCASE("a speculative run stopped by the clock is a prefix of the serial run") {
        o.speculative = 4;
        o.threads = 1;
        Rastrigin q(1);
        const AnnealResult timed = freeform::anneal(q, o);
        CHECK(timed.reason == StopReason::time_budget);
        AnnealOptions serial = o;
        serial.time_budget = 0;
        serial.speculative = 1;
        serial.max_iterations = timed.iterations;
        Rastrigin s(1);
        freeform::anneal(s, serial);
        CHECK(s.accepted == q.accepted);
        CHECK(same_bits(s.x, q.x));
    }
}

TEST_CASE("min_temperature stops before the first iteration below it") {
    for (int speculative : {1, 7}) {
        AnnealOptions o;
        o.initial_temperature = 1.0;
        o.cooling = 0.5;
        o.iterations_per_temperature = 10;
        o.min_temperature = 0.1;  // 1, 0.5, 0.25, 0.125 are run; 0.0625 is not
        o.speculative = speculative;
        o.threads = 1;
        FlatProblem p;
        const AnnealResult r = freeform::anneal(p, o);
        CHECK(r.reason == StopReason::min_temperature);
        CHECK(r.iterations == 40);
        CHECK(p.temperatures.back() == 0.125);
    }
}

TEST_CASE("re-heat after `patience` iterations without a new best, at β times the previous start") {
    for (int speculative : {1, 3}) {
        AnnealOptions o;
        o.initial_temperature = 1.0;
        o.cooling = 0.5;
        o.iterations_per_temperature = 3;
        o.patience = 10;
        o.reheat_factor = 0.25;
        o.max_iterations = 35;
        o.speculative = speculative;
        o.threads = 1;
        FlatProblem p;
        const AnnealResult r = freeform::anneal(p, o);
        CHECK(r.reheats == 3);  // after iterations 10, 20 and 30
        REQUIRE(p.temperatures.size() == 35);
        for (int i = 0; i < 35; ++i) {
            CAPTURE(i);
            const int pass = i / 10;
            const int step = (i % 10) / 3;
            // Powers of two: exact in floating point.
            CHECK(p.temperatures[std::size_t(i)] == std::pow(0.25, pass) * std::pow(0.5, step));
        }
        CHECK(p.temperatures[9] == 0.125);
        CHECK(p.temperatures[10] == 0.25);
        CHECK(p.temperatures[20] == 0.0625);
    }
}

TEST_CASE("sync() is called after every sync_interval iterations, and batch callbacks with it") {
    for (int speculative : {1, 4}) {
        CAPTURE(speculative);
        AnnealOptions o;
        o.max_iterations = 95;
        o.speculative = speculative;
        o.threads = speculative > 1 ? 2 : 1;
        SyncCounter p;
        Recorder rec;
        freeform::anneal(p, o, rec);
        CHECK(p.gaps == std::vector<std::int64_t>(9, 10));
        REQUIRE(rec.batches.size() == 9);
        std::int64_t accepted = 0;
        for (std::size_t k = 0; k < rec.batches.size(); ++k) {
            CHECK(rec.batches[k].iteration == std::int64_t(10 * (k + 1)));
            CHECK(rec.batches[k].iterations == 10);
            CHECK(rec.batches[k].acceptance_rate == doctest::Approx(rec.batches[k].accepted / 10.0));
            accepted += rec.batches[k].accepted;
        }
        CHECK(accepted > 0);
        CHECK(accepted <= p.accepted);
    }
}

TEST_CASE("without sync points, batches come every batch_iterations") {
    AnnealOptions o = rastrigin_options(1);
    o.max_iterations = 100;
    o.batch_iterations = 25;
    Rastrigin p(1);
    Recorder rec;
    const AnnealResult r = freeform::anneal(p, o, rec);
    REQUIRE(rec.batches.size() == 4);
    std::int64_t accepted = 0;
    for (const BatchStats& b : rec.batches) {
        CHECK(b.iterations == 25);
        accepted += b.accepted;
    }
    CHECK(accepted == r.accepted);
}

TEST_CASE("the linear schedule") {
    const freeform::LinearSchedule linear;
    CHECK(linear.temperature(2.0, 0.75, 0) == 2.0);
    CHECK(linear.temperature(2.0, 0.75, 1) == 1.5);
    CHECK(linear.temperature(2.0, 0.75, 4) == 0.0);
    CHECK(linear.temperature(2.0, 0.75, 9) == 0.0);
    CHECK(freeform::reheat_temperature(linear, 2.0, 0.5) == 1.0);

    AnnealOptions o;
    o.initial_temperature = 1.0;
    o.cooling = 0.75;
    o.iterations_per_temperature = 2;
    o.max_iterations = 12;
    FlatProblem p;
    freeform::Annealer<freeform::LinearSchedule>(o).optimize(p);
    CHECK(p.temperatures == std::vector<double>{1, 1, 0.75, 0.75, 0.5, 0.5, 0.25, 0.25, 0, 0, 0, 0});
}

TEST_CASE("an exception from delta() reaches the caller, also from a parallel window") {
    for (int speculative : {1, 4}) {
        CAPTURE(speculative);
        AnnealOptions o;
        o.max_iterations = 10;
        o.speculative = speculative;
        o.threads = 2;
        o.adaptive_speculation = false;  // windows of 4 from the first iteration
        ThrowingProblem p;
        CHECK_THROWS_WITH_AS(freeform::anneal(p, o), "delta failed", std::runtime_error);
        // Serial: proposals 0, 1 and the throwing 2. A parallel window of 4 evaluates all
        // four on the pool's threads before the first error (in proposal order) is rethrown.
        CHECK(p.deltas->load() == (speculative == 1 ? 3 : 4));
    }
}

TEST_CASE("invalid options throw InputError naming the option") {
    auto message_of = [](const AnnealOptions& o) -> std::string {
        try {
            FlatProblem p;
            freeform::anneal(p, o);
        } catch (const InputError& e) {
            return e.what();
        }
        return "no error";
    };
    auto with = [](auto change) {
        AnnealOptions o;
        o.max_iterations = 10;
        change(o);
        return o;
    };
    const auto contains = [](const std::string& s, const std::string& part) { return s.find(part) != s.npos; };

    CHECK(contains(message_of(with([](AnnealOptions& o) { o.cooling = 1.5; })), "anneal.cooling"));
    CHECK(contains(message_of(with([](AnnealOptions& o) { o.cooling = 1.5; })), "1.5"));
    CHECK(contains(message_of(with([](AnnealOptions& o) { o.cooling = 0; })), "anneal.cooling"));
    CHECK(contains(message_of(with([](AnnealOptions& o) { o.initial_temperature = -1; })),
                   "anneal.initial_temperature"));
    CHECK(contains(message_of(with([](AnnealOptions& o) { o.initial_temperature = std::nan(""); })),
                   "anneal.initial_temperature"));
    CHECK(contains(message_of(with([](AnnealOptions& o) { o.iterations_per_temperature = 0; })),
                   "anneal.iterations_per_temperature"));
    CHECK(contains(message_of(with([](AnnealOptions& o) { o.reheat_factor = 2; })), "anneal.reheat_factor"));
    CHECK(contains(message_of(with([](AnnealOptions& o) { o.patience = -1; })), "anneal.patience"));
    CHECK(contains(message_of(with([](AnnealOptions& o) { o.max_iterations = -5; })), "anneal.max_iterations"));
    CHECK(contains(message_of(with([](AnnealOptions& o) { o.time_budget = -1; })), "anneal.time_budget"));
    CHECK(contains(message_of(with([](AnnealOptions& o) { o.target_energy = INFINITY; })), "anneal.target_energy"));
    CHECK(contains(message_of(with([](AnnealOptions& o) { o.stall_iterations = -1; })), "anneal.stall_iterations"));
    CHECK(contains(message_of(with([](AnnealOptions& o) { o.min_temperature = -0.1; })), "anneal.min_temperature"));
    CHECK(contains(message_of(with([](AnnealOptions& o) { o.speculative = 0; })), "anneal.speculative"));
    CHECK(contains(message_of(with([](AnnealOptions& o) { o.threads = -2; })), "anneal.threads"));
    CHECK(contains(message_of(with([](AnnealOptions& o) { o.progress_every = -1; })), "anneal.progress_every"));
    CHECK(contains(message_of(with([](AnnealOptions& o) { o.batch_iterations = -1; })), "anneal.batch_iterations"));
    CHECK(contains(message_of(with([](AnnealOptions& o) { o.max_iterations = 0; })), "no stop rule"));
    CHECK(message_of(with([](AnnealOptions&) {})) == "no error");

    // The Annealer checks its options when it is made, before any problem is seen.
    AnnealOptions bad;
    bad.cooling = 1.5;
    CHECK_THROWS_AS(freeform::Annealer<>{bad}, InputError);
}

TEST_CASE("stop reasons have names") {
    CHECK(std::string(freeform::to_string(StopReason::max_iterations)) == "max_iterations");
    CHECK(std::string(freeform::to_string(StopReason::time_budget)) == "time_budget");
    CHECK(std::string(freeform::to_string(StopReason::target_energy)) == "target_energy");
    CHECK(std::string(freeform::to_string(StopReason::stall)) == "stall");
    CHECK(std::string(freeform::to_string(StopReason::min_temperature)) == "min_temperature");
    CHECK(std::string(freeform::to_string(StopReason::callback)) == "callback");
}

namespace {

// An exchange hook that records what it saw and sets the scale it is told to.
struct ExchangeRecorder {
    std::vector<AnnealExchange> seen;
    double set_scale = 0;  // 0: leave the scale alone
    std::int64_t stop_at = -1;
    bool exchange(AnnealExchange& x) {
        seen.push_back(x);
        if (set_scale > 0) x.temperature_scale = set_scale;
        return x.state.iteration == stop_at;
    }
};

}  // namespace

TEST_CASE("exchange hooks: called every exchange_every iterations; scale 1 leaves the trajectory unchanged") {
    AnnealOptions o = rastrigin_options(7);
    o.max_iterations = 3000;
    o.patience = 400;
    const auto plain = [&] {
        Rastrigin p(3);
        freeform::anneal(p, o);
        return p;
    }();
    for (int speculative : {1, 4}) {
        CAPTURE(speculative);
        AnnealOptions e = o;
        e.exchange_every = 70;
        e.speculative = speculative;
        e.threads = 1;
        Rastrigin p(3);
        ExchangeRecorder rec;
        const AnnealResult r = freeform::anneal(p, e, rec);
        CHECK(r.iterations == 3000);
        CHECK(p.accepted == plain.accepted);
        REQUIRE(rec.seen.size() == std::size_t(3000 / 70));
        for (std::size_t k = 0; k < rec.seen.size(); ++k) {
            CHECK(rec.seen[k].state.iteration == std::int64_t(70 * (k + 1)));
            CHECK(rec.seen[k].temperature_scale == 1.0);
        }
    }
}

TEST_CASE("exchange hooks: a new temperature scale multiplies every later temperature") {
    AnnealOptions o = rastrigin_options(7);
    o.max_iterations = 1000;
    o.patience = 0;
    o.exchange_every = 100;
    o.temperature_scale = 2.0;
    Rastrigin p(3);
    ExchangeRecorder rec;
    rec.set_scale = 3.0;
    rec.stop_at = 500;
    const AnnealResult r = freeform::anneal(p, o, rec);
    CHECK(r.reason == StopReason::callback);
    CHECK(r.iterations == 500);
    REQUIRE(rec.seen.size() == 5);
    const GeometricSchedule g;
    // The first point runs at the initial scale; later ones at the scale the hook set.
    CHECK(rec.seen[0].temperature_scale == 2.0);
    CHECK(rec.seen[0].state.temperature == doctest::Approx(2.0 * g.temperature(10.0, 0.9, 0)));
    CHECK(rec.seen[1].temperature_scale == 3.0);
    CHECK(rec.seen[1].state.temperature == doctest::Approx(3.0 * g.temperature(10.0, 0.9, 0)));
    AnnealOptions bad = o;
    bad.temperature_scale = 0;
    CHECK_THROWS_AS(validate_anneal_options(bad), InputError);
    bad = o;
    bad.exchange_every = -1;
    CHECK_THROWS_AS(validate_anneal_options(bad), InputError);
}

namespace {

// An exchange hook that replaces the problem's state once (as merging replicas do) with
// every coordinate at `value`, which it makes the problem's best copy too.
struct StateReplacer {
    Rastrigin* problem;
    std::int64_t at;
    double value;
    double energy_after = -1;
    std::vector<AnnealExchange> seen = {};
    bool exchange(AnnealExchange& x) {
        seen.push_back(x);
        if (x.state.iteration != at) return false;
        problem->x.fill(value);
        problem->f = problem->total();
        problem->best_x = problem->x;
        energy_after = problem->f;
        x.state_replaced = true;
        return false;
    }
};

}  // namespace

TEST_CASE("exchange hooks: a replaced state is where the run goes on from, and its new best") {
    for (const double value : {0.0, 4.5}) {  // the global minimum, then a state far worse than any seen
        CAPTURE(value);
        AnnealOptions o = rastrigin_options(7);
        o.max_iterations = 2000;
        o.patience = 0;
        o.exchange_every = 100;
        Rastrigin p(3);
        // The worse state comes late, so that the run cannot get back below its old best.
        const std::int64_t at = value == 0.0 ? 1000 : 1900;
        StateReplacer hook{&p, at, value};
        const AnnealResult r = freeform::anneal(p, o, hook);
        REQUIRE(hook.energy_after >= 0);
        REQUIRE(hook.seen.size() == 20);
        const std::size_t k = std::size_t(at / 100);  // hook.seen[k - 1] is the replacement point
        // The next exchange point sees a run that went on from the replaced state.
        CHECK(hook.seen[k].state.best_energy <= hook.energy_after);
        CHECK(r.best_energy <= hook.energy_after);
        // The run's best is the state the problem ends in (not one from before the
        // replacement, which the problem no longer holds).
        CHECK(r.best_energy == doctest::Approx(p.f).epsilon(1e-12));
        if (value == 0.0) CHECK(r.best_energy == 0.0);
        if (value == 4.5) CHECK(r.best_energy > hook.seen[k - 1].state.best_energy);
    }
}
