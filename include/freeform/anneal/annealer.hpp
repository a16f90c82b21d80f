#pragma once
// A generic simulated annealer. It knows nothing of optics: anything that can say what a
// random neighbouring move would change can be annealed.
//
// The problem (checked by AnnealProblem / check_anneal_problem):
//
//   struct MyProblem {
//       struct Move { ... };                          // default-constructible; reused, may hold buffers
//       double energy() const;                        // current energy, to be minimised
//       void propose(CounterRng& rng, double T, Move& m);  // a random neighbour of the current state
//       double delta(Move& m) const;                  // energy change if m were applied
//       void accept(Move& m);                         // apply m: energy() becomes energy() + delta
//       void reject(Move& m);                         // m was evaluated and turned down
//   };
//
// Rules the problem keeps (they are what lets speculative evaluation reproduce the serial
// run exactly):
//   - delta() changes nothing anyone can see; it may be called concurrently on distinct
//     Move objects. It may cache its work inside the Move for accept() to reuse.
//   - propose() draws its randomness from `rng` only, and whatever it changes in the
//     problem must not be read by a later propose() or delta() before the next sync().
//     Several propose() calls can happen before the first of their moves is judged, and
//     a proposed move may be dropped unseen (neither accepted nor rejected).
//   - reject() is feedback only (statistics for a bandit, say): propose() and delta()
//     must not see its effect before the next sync().
//   - accept() is the only call that changes the state propose() and delta() read.
//
// Optional members, found at compile time:
//   void on_new_best()          right after an accepted move that gives a new best energy
//                               (to snapshot the state).
//   void restore_best()         once at the end, so that the problem holds its best state.
//   int sync_interval() const   together with void sync(): the annealer calls sync()
//   void sync()                 after every sync_interval() iterations (asked again after
//                               each sync; a value ≤ 0 means no more syncs). A proposal
//                               policy, such as a bandit, changes only there.
//   double delta(Move& m, TaskPool* pool) const
//                               delta() with the pool's threads working on the one move
//                               (asked when one proposal is judged at a time).
//   void accept(Move& m, TaskPool* pool)
//                               accept() with the pool's threads (null with one thread);
//                               the state must be what accept(m) leaves.
//
// The run. Iteration j runs at the temperature the schedule gives for its place in the
// current pass (the temperature steps down every iterations_per_temperature iterations)
// and is accepted when delta ≤ 0 or u < exp(−delta/T) (Metropolis, reference eq. 3.1).
// After `patience` iterations without a new best, a new pass starts at a lower initial
// temperature (re-heat, reference §3.1). The proposal of iteration j draws from
// CounterRng(key(seed, "propose"), j) and its Metropolis test from an independent key,
// so the run depends on the seed alone, never on the thread count.
//
// Speculative evaluation (options.speculative = P > 1): the proposals of iterations
// j..j+P−1 are made one after another, each at the temperature the serial run would give
// it if the ones before it were rejected, and their deltas are evaluated concurrently.
// Walking them in order, those before the first accepted one are rejected, the first
// accepted one is applied, and the rest are dropped: they never happened, and the next
// window starts just past the accepted iteration. A window never reaches past a point
// where something changes the course of the run (a sync or batch, a progress report,
// a re-heat or stall point, the iteration limit, the minimum temperature), so the
// accepted moves, the energies and the final state are the same for every P and every
// thread count. Only the time budget, which depends on the clock anyway, is checked at
// window boundaries, so a run stopped by it is a prefix of that same trajectory.
//
// Callbacks (the style of ensmallen's): any number of objects, each with any of
//   begin(const AnnealState&)     before the first iteration
//   progress(const AnnealState&)  every progress_every iterations, and once at the end
//   batch(const BatchStats&)      at every sync point (every batch_iterations iterations
//                                 when the problem does not sync)
//   new_best(const AnnealState&)  after an accepted move that gives a new best energy
//   end(const AnnealState&)       after the run, once the problem holds its best state
//   exchange(AnnealExchange&)     every options.exchange_every iterations (only when some
//                                 callback has this hook): it sees the current energy and
//                                 temperature and may set a new temperature scale, the
//                                 factor every later temperature of the run is multiplied
//                                 by (re-heats included). This is the hook of replica
//                                 exchange (freeform/mpi/): replicas at a ladder of scales
//                                 swap their temperatures; nothing here knows about them.
//                                 It may also replace the problem's state (domain
//                                 decomposition: replicas merge their surfaces) and say
//                                 so with state_replaced: the run then goes on from the
//                                 problem's new energy, which is also its new best.
// A hook that returns a value convertible to bool stops the run after that point when
// it returns true (end's value is ignored). Every callback is called in the order given,
// even when an earlier one asked to stop.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <concepts>
#include <cstdint>
#include <exception>
#include <limits>
#include <memory>
#include <optional>
#include <sstream>
#include <span>
#include <string>
#include <type_traits>
#include <utility>
#include <vector>

#include "../core/error.hpp"
#include "../core/exec.hpp"
#include "../core/rng.hpp"
#include "../core/task_pool.hpp"
#include "schedule.hpp"

namespace freeform {

struct AnnealOptions {
    std::uint64_t seed = 1;

    // Cooling: T = schedule(t0, cooling, step), step = iterations into the pass divided
    // by iterations_per_temperature. With the geometric schedule T ← cooling·T per step.
    double initial_temperature = 1.0;
    double cooling = 0.95;  // in (0, 1]; 1 holds the temperature
    std::int64_t iterations_per_temperature = 100;

    // Re-heat: after `patience` iterations without a new best (counted from the last new
    // best or the last re-heat), start a new pass at reheat_factor × the previous pass's
    // initial temperature. patience 0 never re-heats.
    double reheat_factor = 0.5;  // in (0, 1]
    std::int64_t patience = 0;

    // Stop rules; the first one met ends the run. At least one must be set unless a
    // callback is given (a callback can stop the run too).
    std::int64_t max_iterations = 0;  // 0 = no limit
    double time_budget = 0;           // seconds, 0 = none; the clock is read about once a millisecond
    double target_energy = std::numeric_limits<double>::quiet_NaN();  // stop when best ≤ it; NaN or negative = off
    std::int64_t stall_iterations = 0;  // stop after this many iterations without a new best; 0 = off
    double min_temperature = 0;         // stop when the next iteration would run below it; 0 = off

    // Speculative evaluation: proposals judged per window, and the OpenMP threads that
    // evaluate their deltas (0 = OpenMP's default). Neither changes the result.
    int speculative = 1;
    int threads = 0;
    // Measure serial against speculative windows during the run and use the faster
    // (the trajectory is the same either way). Off: always windows of `speculative`.
    bool adaptive_speculation = true;

    // Reporting: progress callbacks every progress_every iterations (0 = only at the end);
    // batch callbacks every batch_iterations when the problem has no sync points (0 = none).
    std::int64_t progress_every = 0;
    std::int64_t batch_iterations = 1000;

    // Temperature scale: every temperature the schedule gives is multiplied by it (1 =
    // the schedule's own, exactly). An exchange hook may change it during the run.
    double temperature_scale = 1.0;
    // Iterations between calls of the callbacks' exchange hooks (0 = never). Like sync
    // points, exchange points bound speculative windows, so they do not change the
    // trajectory by themselves.
    std::int64_t exchange_every = 0;
    // End holding the best state seen (problems with restore_best()). Off: the caller
    // decides what to keep (the designer judges the best with held-out rays first, so that
    // the problem is retraced once, to the state it keeps: design/designer.hpp).
    bool restore_best = true;
};

// no_gain is the designer's (design/designer.hpp, StageGainWatch): a stage that had
// stopped paying, ended so that the next one gets its time. The annealer never returns it.
enum class StopReason { max_iterations, time_budget, target_energy, stall, min_temperature, callback, no_gain };

inline const char* to_string(StopReason reason) {
    switch (reason) {
        case StopReason::max_iterations: return "max_iterations";
        case StopReason::time_budget: return "time_budget";
        case StopReason::target_energy: return "target_energy";
        case StopReason::stall: return "stall";
        case StopReason::min_temperature: return "min_temperature";
        case StopReason::callback: return "callback";
        case StopReason::no_gain: return "no_gain";
    }
    return "unknown";
}

// A snapshot of the run handed to callbacks.
struct AnnealState {
    std::int64_t iteration = 0;  // iterations done so far
    double temperature = 0;      // the temperature the next iteration runs at
    double energy = 0;           // current energy
    double best_energy = 0;
    std::int64_t accepted = 0;  // accepted moves so far
    double seconds = 0;         // since the run started
    double iterations_per_second = 0;
    int reheats = 0;
};

// What an exchange hook sees and may change (AnnealOptions::exchange_every).
struct AnnealExchange {
    AnnealState state;               // state.temperature: the next iteration's, scale included
    double temperature_scale = 1.0;  // in: the current scale; out: the scale from now on (> 0)
    // out: the hook replaced the problem's state (heights); its energy is re-read and
    // becomes the run's best (the problem's own best copy is the hook's business).
    bool state_replaced = false;
};

// What happened since the previous sync/batch point.
struct BatchStats {
    std::int64_t iteration = 0;   // iterations done when the batch closed
    std::int64_t iterations = 0;  // iterations in this batch
    std::int64_t accepted = 0;
    double acceptance_rate = 0;
    double mean_accepted_delta = 0;  // 0 when nothing was accepted
    double temperature = 0;          // the temperature the next iteration runs at
};

struct AnnealResult {
    double best_energy = 0;
    double final_energy = 0;  // energy when the run stopped, before restore_best()
    std::int64_t iterations = 0;
    std::int64_t accepted = 0;
    std::int64_t proposals_evaluated = 0;  // deltas computed, dropped speculative ones included
    double seconds = 0;
    int reheats = 0;
    StopReason reason = StopReason::max_iterations;
};

// ---------------------------------------------------------------------------------------
// The problem concept, in parts so that check_anneal_problem can say which part is missing.
namespace anneal_detail {

template <class P>
concept HasMove = requires { typename P::Move; } && std::default_initializable<typename P::Move>;

template <class P>
concept HasEnergy = requires(const P& cp) {
    { cp.energy() } -> std::convertible_to<double>;
};

template <class P>
concept HasPropose = HasMove<P> && requires(P& p, typename P::Move& m, CounterRng& rng, double temperature) {
    p.propose(rng, temperature, m);
};

template <class P>
concept HasDelta = HasMove<P> && requires(const P& cp, typename P::Move& m) {
    { cp.delta(m) } -> std::convertible_to<double>;
};

template <class P>
concept HasAcceptReject = HasMove<P> && requires(P& p, typename P::Move& m) {
    p.accept(m);
    p.reject(m);
};

template <class P>
concept HasOnNewBest = requires(P& p) { p.on_new_best(); };

template <class P>
concept HasRestoreBest = requires(P& p) { p.restore_best(); };

template <class P>
concept HasSyncInterval = requires(const P& cp) {
    { cp.sync_interval() } -> std::convertible_to<std::int64_t>;
};

template <class P>
concept HasSync = requires(P& p) { p.sync(); };

}  // namespace anneal_detail

template <class P>
concept AnnealProblem = anneal_detail::HasMove<P> && anneal_detail::HasEnergy<P> && anneal_detail::HasPropose<P> &&
                        anneal_detail::HasDelta<P> && anneal_detail::HasAcceptReject<P>;

// Checks a problem type up front with one readable message per missing piece; returns
// whether P can be annealed. Annealer::optimize calls it, so a type that does not fit
// fails there with these messages rather than deep inside the loop.
template <class P>
constexpr bool check_anneal_problem() {
    using namespace anneal_detail;
    static_assert(HasMove<P>,
                  "freeform::anneal: the problem type must declare a default-constructible nested type `Move` "
                  "(one proposed change; the annealer reuses Move objects); see freeform/anneal/annealer.hpp");
    static_assert(HasEnergy<P>,
                  "freeform::anneal: the problem type must provide `double energy() const` (the current value "
                  "of the objective to minimise); see freeform/anneal/annealer.hpp");
    static_assert(!HasMove<P> || HasPropose<P>,
                  "freeform::anneal: the problem type must provide `void propose(CounterRng& rng, double "
                  "temperature, Move& move)` filling `move` with a random neighbour; see freeform/anneal/annealer.hpp");
    static_assert(!HasMove<P> || HasDelta<P>,
                  "freeform::anneal: the problem type must provide `double delta(Move& move) const`: the energy "
                  "change if `move` were applied, with no visible state change; see freeform/anneal/annealer.hpp");
    static_assert(!HasMove<P> || HasAcceptReject<P>,
                  "freeform::anneal: the problem type must provide `void accept(Move& move)` (apply it) and "
                  "`void reject(Move& move)` (feedback on a rejected move, may do nothing); see "
                  "freeform/anneal/annealer.hpp");
    static_assert(HasSyncInterval<P> == HasSync<P>,
                  "freeform::anneal: the problem type provides only one of `int sync_interval() const` and "
                  "`void sync()`; both are needed for sync points");
    return AnnealProblem<P>;
}

// ---------------------------------------------------------------------------------------
// Callbacks.
namespace anneal_detail {

template <class C>
concept HasBeginHook = requires(C& c, const AnnealState& s) { c.begin(s); };
template <class C>
concept HasProgressHook = requires(C& c, const AnnealState& s) { c.progress(s); };
template <class C>
concept HasBatchHook = requires(C& c, const BatchStats& b) { c.batch(b); };
template <class C>
concept HasNewBestHook = requires(C& c, const AnnealState& s) { c.new_best(s); };
template <class C>
concept HasEndHook = requires(C& c, const AnnealState& s) { c.end(s); };

template <class C>
concept HasExchangeHook = requires(C& c, AnnealExchange& x) { c.exchange(x); };

template <class C>
concept AnnealCallback = HasBeginHook<C> || HasProgressHook<C> || HasBatchHook<C> || HasNewBestHook<C> ||
                         HasEndHook<C> || HasExchangeHook<C>;

// Calls a hook; true when it returned something that converts to true.
template <class F>
bool stop_requested(F&& hook) {
    if constexpr (std::is_void_v<std::invoke_result_t<F>>) {
        hook();
        return false;
    } else {
        return static_cast<bool>(hook());
    }
}

inline std::string option_value(double v) {
    std::ostringstream out;
    out << v;
    return out.str();
}

}  // namespace anneal_detail

// Throws InputError naming the first bad option.
inline void validate_anneal_options(const AnnealOptions& o) {
    using anneal_detail::option_value;
    const auto fail = [](const std::string& what) { throw InputError("anneal." + what); };
    if (!std::isfinite(o.initial_temperature) || o.initial_temperature <= 0)
        fail("initial_temperature must be a finite number > 0, got " + option_value(o.initial_temperature));
    if (!(o.cooling > 0 && o.cooling <= 1)) fail("cooling must be in (0, 1], got " + option_value(o.cooling));
    if (o.iterations_per_temperature < 1)
        fail("iterations_per_temperature must be ≥ 1, got " + std::to_string(o.iterations_per_temperature));
    if (!(o.reheat_factor > 0 && o.reheat_factor <= 1))
        fail("reheat_factor must be in (0, 1], got " + option_value(o.reheat_factor));
    if (o.patience < 0) fail("patience must be ≥ 0 (0 = never re-heat), got " + std::to_string(o.patience));
    if (o.max_iterations < 0)
        fail("max_iterations must be ≥ 0 (0 = no limit), got " + std::to_string(o.max_iterations));
    if (!std::isfinite(o.time_budget) || o.time_budget < 0)
        fail("time_budget must be a finite number of seconds ≥ 0 (0 = none), got " + option_value(o.time_budget));
    if (std::isinf(o.target_energy))
        fail("target_energy must be finite (NaN or negative = off), got " + option_value(o.target_energy));
    if (o.stall_iterations < 0)
        fail("stall_iterations must be ≥ 0 (0 = off), got " + std::to_string(o.stall_iterations));
    if (!std::isfinite(o.min_temperature) || o.min_temperature < 0)
        fail("min_temperature must be a finite number ≥ 0 (0 = off), got " + option_value(o.min_temperature));
    if (o.speculative < 1) fail("speculative must be ≥ 1, got " + std::to_string(o.speculative));
    if (o.threads < 0) fail("threads must be ≥ 0 (0 = OpenMP default), got " + std::to_string(o.threads));
    if (o.progress_every < 0)
        fail("progress_every must be ≥ 0 (0 = only at the end), got " + std::to_string(o.progress_every));
    if (o.batch_iterations < 0)
        fail("batch_iterations must be ≥ 0 (0 = none), got " + std::to_string(o.batch_iterations));
    if (!std::isfinite(o.temperature_scale) || o.temperature_scale <= 0)
        fail("temperature_scale must be a finite number > 0, got " + option_value(o.temperature_scale));
    if (o.exchange_every < 0)
        fail("exchange_every must be ≥ 0 (0 = never), got " + std::to_string(o.exchange_every));
}

namespace anneal_detail {

inline constexpr std::uint64_t propose_stream = 0x70726f706f7365ULL;  // "propose"
inline constexpr std::uint64_t metropolis_stream = 0x6d6574726f706fULL;  // "metropo"
// The most iterations between two reads of the clock for the time budget.
inline constexpr std::int64_t max_clock_interval = 1024;
inline constexpr std::int64_t never = std::numeric_limits<std::int64_t>::max();

inline bool target_enabled(double target) { return !std::isnan(target) && target >= 0; }

// Whether a problem's delta() may run on several moves at once: true unless the problem
// says otherwise with `static constexpr bool concurrent_deltas = false` (a backend that
// must show a move to shared state to evaluate it, as the Embree one does). Speculative
// windows of such a problem evaluate their proposals one after another: the trajectory
// is the same, only the speed differs.
template <class Problem>
constexpr bool concurrent_deltas_of() {
    if constexpr (requires { Problem::concurrent_deltas; })
        return Problem::concurrent_deltas;
    else
        return true;
}

// One run of the annealer: the loop state and the steps of the loop.
template <class Problem, class Schedule>
class AnnealRun {
public:
    AnnealRun(Problem& problem, const AnnealOptions& options, const Schedule& schedule)
        : problem_(problem),
          options_(options),
          schedule_(schedule),
          propose_key_(hash_combine(options.seed, propose_stream)),
          metropolis_key_(hash_combine(options.seed, metropolis_stream)),
          moves_(static_cast<std::size_t>(options.speculative)),
          deltas_(static_cast<std::size_t>(options.speculative)),
          temperatures_(static_cast<std::size_t>(options.speculative)),
          errors_(static_cast<std::size_t>(options.speculative)),
          parallel_mode_(options.speculative > 1 && !options.adaptive_speculation) {}

    template <class... Cs>
    AnnealResult run(Cs&... callbacks) {
        start_ = std::chrono::steady_clock::now();
        pass_t0_ = options_.initial_temperature;
        scale_ = options_.temperature_scale;
        if constexpr ((HasExchangeHook<Cs> || ...)) {
            if (options_.exchange_every > 0) next_exchange_ = options_.exchange_every;
        }
        energy_ = static_cast<double>(problem_.energy());
        best_ = energy_;
        if (options_.progress_every > 0) next_progress_ = options_.progress_every;

        if constexpr (HasSyncInterval<Problem>) {
            const auto interval = static_cast<std::int64_t>(problem_.sync_interval());
            next_batch_ = interval > 0 ? interval : never;
        } else if constexpr ((HasBatchHook<Cs> || ...)) {
            if (options_.batch_iterations > 0) next_batch_ = options_.batch_iterations;
        }

        bool stop = false;
        {
            const AnnealState s = state();
            call_each(stop, [&](auto& c) { return hook_begin(c, s); }, callbacks...);
        }
        StopReason reason{};
        for (;;) {
            if (const auto r = stop_reason(stop)) {
                reason = *r;
                break;
            }
            stop = step(callbacks...);
        }

        if (last_progress_ != iteration_) {
            const AnnealState s = state();
            bool ignored = false;
            call_each(ignored, [&](auto& c) { return hook_progress(c, s); }, callbacks...);
        }
        AnnealResult result;
        result.best_energy = best_;
        result.final_energy = energy_;
        result.iterations = iteration_;
        result.accepted = accepted_;
        result.proposals_evaluated = proposals_evaluated_;
        result.reheats = reheats_;
        result.reason = reason;
        result.seconds = seconds();
        if constexpr (HasRestoreBest<Problem>)
            if (options_.restore_best) problem_.restore_best();
        {
            const AnnealState s = state();
            bool ignored = false;
            call_each(ignored, [&](auto& c) { return hook_end(c, s); }, callbacks...);
        }
        return result;
    }

private:
    // Calls hook(c) on every callback in order; any true sets `stop`.
    template <class Hook, class... Cs>
    static void call_each(bool& stop, Hook&& hook, Cs&... callbacks) {
        ((hook(callbacks) ? (void)(stop = true) : (void)0), ...);
    }

    template <class C>
    static bool hook_begin(C& c, const AnnealState& s) {
        if constexpr (HasBeginHook<C>) return stop_requested([&] { return c.begin(s); });
        return false;
    }
    template <class C>
    static bool hook_progress(C& c, const AnnealState& s) {
        if constexpr (HasProgressHook<C>) return stop_requested([&] { return c.progress(s); });
        return false;
    }
    template <class C>
    static bool hook_batch(C& c, const BatchStats& b) {
        if constexpr (HasBatchHook<C>) return stop_requested([&] { return c.batch(b); });
        return false;
    }
    template <class C>
    static bool hook_end(C& c, const AnnealState& s) {
        if constexpr (HasEndHook<C>) c.end(s);  // its value is ignored: the run is over
        return false;
    }
    template <class C>
    static bool hook_exchange(C& c, AnnealExchange& x) {
        if constexpr (HasExchangeHook<C>) return stop_requested([&] { return c.exchange(x); });
        return false;
    }
    template <class C>
    static bool hook_new_best(C& c, const AnnealState& s) {
        if constexpr (HasNewBestHook<C>) return stop_requested([&] { return c.new_best(s); });
        return false;
    }

    double seconds() const {
        return std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
    }

    // Temperature of iteration j of the current pass; cached per temperature step, the
    // unit in which it changes.
    double temperature_at(std::int64_t j) {
        const std::int64_t step = (j - pass_start_) / options_.iterations_per_temperature;
        if (step != cached_step_) {
            cached_step_ = step;
            // × 1.0 leaves the schedule's value unchanged bit for bit.
            cached_temperature_ =
                static_cast<double>(schedule_.temperature(pass_t0_, options_.cooling, step)) * scale_;
        }
        return cached_temperature_;
    }

    AnnealState state() {
        AnnealState s;
        s.iteration = iteration_;
        s.temperature = temperature_at(iteration_);
        s.energy = energy_;
        s.best_energy = best_;
        s.accepted = accepted_;
        s.seconds = seconds();
        s.iterations_per_second = s.seconds > 0 ? static_cast<double>(iteration_) / s.seconds : 0.0;
        s.reheats = reheats_;
        return s;
    }

    std::optional<StopReason> stop_reason(bool callback_stop) {
        if (callback_stop) return StopReason::callback;
        if (target_enabled(options_.target_energy) && best_ <= options_.target_energy)
            return StopReason::target_energy;
        if (options_.max_iterations > 0 && iteration_ >= options_.max_iterations) return StopReason::max_iterations;
        if (options_.stall_iterations > 0 && since_best_ >= options_.stall_iterations) return StopReason::stall;
        if (options_.min_temperature > 0 && temperature_at(iteration_) < options_.min_temperature)
            return StopReason::min_temperature;
        if (options_.time_budget > 0 && iteration_ >= next_clock_check_) {
            const double now = seconds();
            if (now >= options_.time_budget) return StopReason::time_budget;
            // Aim at about a millisecond between reads: cheap iterations read the clock
            // every few dozen or hundred iterations, slow ones at every window.
            const double since = now - last_clock_seconds_;
            if (since < 0.5e-3) clock_interval_ = std::min<std::int64_t>(clock_interval_ * 2, max_clock_interval);
            if (since > 2e-3) clock_interval_ = std::max<std::int64_t>(clock_interval_ / 2, 1);
            last_clock_seconds_ = now;
            next_clock_check_ = iteration_ + clock_interval_;
        }
        return std::nullopt;
    }

    // The last iteration (exclusive) a window starting now may reach without passing a
    // point where the serial run would do something other than the next iteration.
    std::int64_t window_end() const {
        std::int64_t end = iteration_ + (parallel_mode_ ? options_.speculative : 1);
        end = std::min({end, next_batch_, next_progress_, next_exchange_});
        if (options_.max_iterations > 0) end = std::min(end, options_.max_iterations);
        if (options_.patience > 0) end = std::min(end, iteration_ + (options_.patience - since_reheat_));
        if (options_.stall_iterations > 0) end = std::min(end, iteration_ + (options_.stall_iterations - since_best_));
        return end;
    }

    bool metropolis(std::int64_t j, double delta, double temperature) const {
        if (delta <= 0) return true;
        if (!(temperature > 0)) return false;  // at T = 0 only non-worsening moves pass
        // A NaN delta fails this comparison too: it is never accepted.
        CounterRng rng(metropolis_key_, static_cast<std::uint64_t>(j));
        return rng.uniform() < std::exp(-delta / temperature);
    }

    // Whether the problem evaluates a window's moves together (design/problem.hpp,
    // trace/window.hpp; on a device, say), whatever the annealer's thread count.
    bool windows_together() const {
        const Problem& cp = problem_;
        if constexpr (requires(std::span<typename Problem::Move> m, std::span<double> d) {
                          cp.delta_window(m, d);
                          { cp.window_evaluation() } -> std::convertible_to<bool>;
                      })
            return cp.window_evaluation();
        return false;
    }

    void evaluate(int count) {
        const Problem& cp = problem_;
        proposals_evaluated_ += count;
        // A problem that evaluates a window's moves together gets them all at once: the
        // same deltas bit for bit.
        if constexpr (requires(std::span<typename Problem::Move> m, std::span<double> d) { cp.delta_window(m, d); }) {
            if (count > 1 && windows_together()) {
                cp.delta_window(std::span(moves_).first(std::size_t(count)),
                                std::span(deltas_).first(std::size_t(count)));
                return;
            }
        }
        if (count == 1 && options_.threads != 1) {
            // One proposal: a problem that can split its evaluation over threads gets them.
            if constexpr (requires(typename Problem::Move& m, TaskPool* pool) { cp.delta(m, pool); }) {
                if (!pool_) pool_ = std::make_unique<TaskPool>(thread_count(exec::omp_t{options_.threads}));
                deltas_[0] = static_cast<double>(cp.delta(moves_[0], pool_.get()));
                return;
            }
        }
        if (count == 1 || options_.threads == 1 || !concurrent_deltas_of<Problem>()) {
            for (int k = 0; k < count; ++k) deltas_[k] = static_cast<double>(cp.delta(moves_[k]));
            return;
        }
        // Exceptions must not escape a worker; carry them out and rethrow the first in
        // proposal order.
        if (!pool_) pool_ = std::make_unique<TaskPool>(thread_count(exec::omp_t{options_.threads}));
        pool_->run(count, [&](int k) {
            try {
                deltas_[k] = static_cast<double>(cp.delta(moves_[k]));
            } catch (...) {
                errors_[k] = std::current_exception();
            }
        });
        for (int k = 0; k < count; ++k)
            if (errors_[k]) {
                const std::exception_ptr error = errors_[k];
                std::fill(errors_.begin(), errors_.end(), nullptr);
                std::rethrow_exception(error);
            }
    }

    // Speculation pays only when a delta costs much more than waking the other threads,
    // and not at all when the machine has no idle core for them. Since the trajectory is
    // the same for every window size, the run measures both and keeps the faster: it
    // probes serial windows now and then and compares iterations per second. One thread
    // has nothing to speculate with, unless the problem evaluates windows on its own.
    void adapt_window(std::int64_t iterations, double seconds) {
        if (!options_.adaptive_speculation || options_.speculative <= 1 ||
            (options_.threads == 1 && !windows_together())) {
            parallel_mode_ = options_.speculative > 1 && !options_.adaptive_speculation;
            return;
        }
        Rate& r = parallel_mode_ ? parallel_rate_ : serial_rate_;
        r.iterations += iterations;
        r.seconds += seconds;
        if (++mode_windows_ < (parallel_mode_ ? 128 : 64)) return;
        mode_windows_ = 0;
        if (probing_) {  // a period in the other mode just ended: keep the faster
            probing_ = false;
            parallel_mode_ = parallel_rate_.per_second() >= serial_rate_.per_second();
        } else if (++periods_ % 16 == 1) {  // now and then, measure the other mode again
            probing_ = true;
            parallel_mode_ = !parallel_mode_;
        }
        (parallel_mode_ ? parallel_rate_ : serial_rate_) = {};
    }

    template <class... Cs>
    bool step(Cs&... callbacks) {
        const auto window_start = std::chrono::steady_clock::now();
        const bool stop = step_window(callbacks...);
        adapt_window(last_window_iterations_,
                     std::chrono::duration<double>(std::chrono::steady_clock::now() - window_start).count());
        return stop;
    }

    // Runs one window of iterations (one iteration when not speculative); true when a
    // callback asked to stop.
    template <class... Cs>
    bool step_window(Cs&... callbacks) {
        const std::int64_t first = iteration_;
        const int count = propose_window(first);
        const int taken = first_accepted(first, count);
        const int done = taken >= 0 ? taken + 1 : count;
        last_window_iterations_ = done;
        iteration_ = first + done;
        batch_iterations_ += done;
        // Every iteration but an accepted new best extends the run without improvement.
        since_best_ += done;
        since_reheat_ += done;

        bool stop = false;
        if (taken >= 0) accept_move(taken, stop, callbacks...);
        if (iteration_ == next_batch_) end_batch(stop, callbacks...);
        if (options_.patience > 0 && since_reheat_ >= options_.patience) reheat();
        if (iteration_ == next_exchange_) run_exchange(stop, callbacks...);
        if (iteration_ == next_progress_) {
            last_progress_ = iteration_;
            next_progress_ += options_.progress_every;
            const AnnealState s = state();
            call_each(stop, [&](auto& c) { return hook_progress(c, s); }, callbacks...);
        }
        return stop;
    }

    // Proposes and evaluates the moves of the window that starts at iteration `first`;
    // returns how many there are.
    int propose_window(std::int64_t first) {
        const std::int64_t end = window_end();
        int count = 0;
        for (std::int64_t j = first; j < end; ++j) {
            const double t = temperature_at(j);
            // The serial run would stop before j: the minimum-temperature rule.
            if (options_.min_temperature > 0 && t < options_.min_temperature) break;
            temperatures_[count++] = t;
        }
        for (int k = 0; k < count; ++k) {
            CounterRng rng(propose_key_, static_cast<std::uint64_t>(first + k));
            problem_.propose(rng, temperatures_[k], moves_[k]);
        }
        evaluate(count);
        return count;
    }

    // The first of the window's `count` moves that the Metropolis rule accepts (the ones
    // before it are rejected), or -1 when none is.
    int first_accepted(std::int64_t first, int count) {
        for (int k = 0; k < count; ++k) {
            if (metropolis(first + k, deltas_[k], temperatures_[k])) return k;
            problem_.reject(moves_[k]);
        }
        return -1;
    }

    // Applies the window's accepted move `taken`, and tells the callbacks of a new best.
    template <class... Cs>
    void accept_move(int taken, bool& stop, Cs&... callbacks) {
        if constexpr (requires(typename Problem::Move& m, TaskPool* pool) { problem_.accept(m, pool); })
            problem_.accept(moves_[taken], pool_.get());
        else
            problem_.accept(moves_[taken]);
        energy_ = static_cast<double>(problem_.energy());
        ++accepted_;
        ++batch_accepted_;
        batch_delta_sum_ += deltas_[taken];
        if (energy_ < best_) {
            best_ = energy_;
            since_best_ = 0;
            since_reheat_ = 0;
            if constexpr (HasOnNewBest<Problem>) problem_.on_new_best();
            const AnnealState s = state();
            call_each(stop, [&](auto& c) { return hook_new_best(c, s); }, callbacks...);
        }
    }

    // At the end of a batch: syncs the problem, reports the batch's statistics and
    // starts the next batch.
    template <class... Cs>
    void end_batch(bool& stop, Cs&... callbacks) {
        if constexpr (HasSync<Problem>) problem_.sync();
        BatchStats b;
        b.iteration = iteration_;
        b.iterations = batch_iterations_;
        b.accepted = batch_accepted_;
        b.acceptance_rate = batch_iterations_ > 0 ? double(batch_accepted_) / double(batch_iterations_) : 0.0;
        b.mean_accepted_delta = batch_accepted_ > 0 ? batch_delta_sum_ / double(batch_accepted_) : 0.0;
        b.temperature = temperature_at(iteration_);
        call_each(stop, [&](auto& c) { return hook_batch(c, b); }, callbacks...);
        batch_iterations_ = batch_accepted_ = 0;
        batch_delta_sum_ = 0;
        if constexpr (HasSyncInterval<Problem>) {
            const auto interval = static_cast<std::int64_t>(problem_.sync_interval());
            next_batch_ = interval > 0 ? iteration_ + interval : never;
        } else {
            next_batch_ = iteration_ + options_.batch_iterations;
        }
    }

    // The patience rule: a new cooling pass from a raised temperature.
    void reheat() {
        pass_t0_ = reheat_temperature(schedule_, pass_t0_, options_.reheat_factor);
        pass_start_ = iteration_;
        cached_step_ = -1;
        since_reheat_ = 0;
        ++reheats_;
    }

    // Calls the exchange hooks, which may rescale the temperature or replace the state.
    template <class... Cs>
    void run_exchange(bool& stop, Cs&... callbacks) {
        next_exchange_ += options_.exchange_every;
        AnnealExchange x;
        x.state = state();
        x.temperature_scale = scale_;
        call_each(stop, [&](auto& c) { return hook_exchange(c, x); }, callbacks...);
        if (!(std::isfinite(x.temperature_scale) && x.temperature_scale > 0))
            throw InputError("anneal: an exchange hook set temperature_scale to " + option_value(x.temperature_scale) +
                             "; it must be a finite number > 0");
        if (x.temperature_scale != scale_) {
            scale_ = x.temperature_scale;
            cached_step_ = -1;
        }
        if (x.state_replaced) {
            energy_ = static_cast<double>(problem_.energy());
            best_ = energy_;
        }
    }

    Problem& problem_;
    const AnnealOptions& options_;
    const Schedule& schedule_;
    std::uint64_t propose_key_;
    std::uint64_t metropolis_key_;
    std::vector<typename Problem::Move> moves_;
    std::vector<double> deltas_;
    std::vector<double> temperatures_;
    std::vector<std::exception_ptr> errors_;
    bool parallel_mode_;  // adaptive runs start serial; the first period probes speculative windows

    struct Rate {
        std::int64_t iterations = 0;
        double seconds = 0;
        double per_second() const { return seconds > 0 ? double(iterations) / seconds : 0.0; }
    };
    Rate parallel_rate_, serial_rate_;
    bool probing_ = false;
    std::int64_t mode_windows_ = 0, periods_ = 0, last_window_iterations_ = 0;

    std::unique_ptr<TaskPool> pool_;  // started on the first parallel window
    std::chrono::steady_clock::time_point start_{};
    std::int64_t iteration_ = 0;
    std::int64_t accepted_ = 0;
    std::int64_t proposals_evaluated_ = 0;
    double energy_ = 0;
    double best_ = 0;
    std::int64_t since_best_ = 0;    // iterations since the last new best (stall rule)
    std::int64_t since_reheat_ = 0;  // ... or since the last re-heat (patience rule)
    int reheats_ = 0;

    double pass_t0_ = 0;
    double scale_ = 1.0;  // temperature scale (options.temperature_scale, then exchange hooks)
    std::int64_t pass_start_ = 0;
    std::int64_t cached_step_ = -1;
    double cached_temperature_ = 0;

    std::int64_t next_batch_ = never;
    std::int64_t batch_iterations_ = 0;
    std::int64_t batch_accepted_ = 0;
    double batch_delta_sum_ = 0;

    std::int64_t next_progress_ = never;
    std::int64_t next_exchange_ = never;
    std::int64_t last_progress_ = -1;
    std::int64_t next_clock_check_ = 0;
    std::int64_t clock_interval_ = 1;  // grows while reads come more often than every 0.5 ms
    double last_clock_seconds_ = 0;
};

}  // namespace anneal_detail

// The annealer: options and a cooling schedule, validated once; optimize() runs it on a
// problem. Annealer<>{options}.optimize(problem, callbacks...) uses the geometric schedule.
template <CoolingSchedule Schedule = GeometricSchedule>
class Annealer {
public:
    explicit Annealer(const AnnealOptions& options = {}, Schedule schedule = {})
        : options_(options), schedule_(std::move(schedule)) {
        validate_anneal_options(options_);
    }

    const AnnealOptions& options() const { return options_; }
    const Schedule& schedule() const { return schedule_; }

    // Anneals `problem` in place; it ends holding its best state when it provides
    // restore_best(). Throws InputError when no stop rule is set and no callback is given.
    template <class Problem, class... Callbacks>
    AnnealResult optimize(Problem& problem, Callbacks&&... callbacks) const {
        constexpr bool fits = check_anneal_problem<Problem>();
        static_assert((anneal_detail::AnnealCallback<std::remove_cvref_t<Callbacks>> && ...),
                      "freeform::anneal: every callback needs at least one of begin(const AnnealState&), "
                      "progress(const AnnealState&), batch(const BatchStats&), new_best(const AnnealState&), "
                      "end(const AnnealState&); see freeform/anneal/annealer.hpp");
        if constexpr (fits) {
            if constexpr (sizeof...(Callbacks) == 0) {
                const AnnealOptions& o = options_;
                if (o.max_iterations == 0 && o.time_budget == 0 && o.stall_iterations == 0 &&
                    o.min_temperature == 0 && !anneal_detail::target_enabled(o.target_energy))
                    throw InputError(
                        "anneal: no stop rule is set; set anneal.max_iterations, anneal.time_budget, "
                        "anneal.stall_iterations, anneal.min_temperature or anneal.target_energy");
            }
            anneal_detail::AnnealRun<Problem, Schedule> run(problem, options_, schedule_);
            return run.run(callbacks...);
        } else {
            return {};
        }
    }

private:
    AnnealOptions options_;
    Schedule schedule_;
};

// Shorthand for Annealer<GeometricSchedule>(options).optimize(problem, callbacks...).
template <class Problem, class... Callbacks>
AnnealResult anneal(Problem& problem, const AnnealOptions& options, Callbacks&&... callbacks) {
    return Annealer<>(options).optimize(problem, std::forward<Callbacks>(callbacks)...);
}

}  // namespace freeform
