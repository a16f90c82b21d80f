#pragma once
// Choosing the kernel of the next move: a multi-armed bandit over the kernel bank.
//
// No single kernel shape suits every target (reference §4.3), and trying shapes at
// random wastes moves on the ones that do not fit. Each kernel is an arm; a pull is one
// proposed move; its reward is the error decrease of the move if it was accepted and
// improved the error, else 0. The reference learns a table of rewards per shape (§4.3.2,
// "history-based decision strategy", a one-state Q-learning) with a probability floor
// and batched updates; the classes below implement that and the standard bandit
// policies next to it, so they can be compared on the same runs.
//
// Batching is part of the contract, not an optimisation: choose() depends only on the
// state as of the last sync() and on the random numbers passed in, so P proposals can be
// drawn, evaluated in parallel and their outcomes reported afterwards in proposal order,
// and the run is the same for any P. Every choose() draws exactly one uniform number.
#include <algorithm>
#include <cmath>
#include <concepts>
#include <cstdint>
#include <limits>
#include <numeric>
#include <optional>
#include <sstream>
#include <string>
#include <string_view>
#include <type_traits>
#include <utility>
#include <variant>
#include <vector>

#include "../core/error.hpp"
#include "../core/rng.hpp"
#include "options.hpp"

namespace freeform {

// What the proposal machinery needs from a kernel-choice policy.
template <class B>
concept Bandit = requires(B& b, const B& cb, CounterRng& rng, int arm, double reward) {
    { cb.arms() } -> std::convertible_to<int>;
    { cb.choose(rng) } -> std::convertible_to<int>;
    b.update(arm, reward);
    b.sync();
    { cb.sync_interval() } -> std::convertible_to<int>;
    { cb.weights() } -> std::convertible_to<std::vector<double>>;
};

// `static_assert(check_bandit<MyBandit>());` says which member is missing instead of
// printing the whole failed constraint.
template <class B>
consteval bool check_bandit() {
    static_assert(requires(const B& b) { { b.arms() } -> std::convertible_to<int>; },
                  "a Bandit needs `int arms() const`: the number of kernels it chooses from");
    static_assert(requires(const B& b, CounterRng& r) { { b.choose(r) } -> std::convertible_to<int>; },
                  "a Bandit needs `int choose(CounterRng&) const`, depending only on the state at the last sync()");
    static_assert(requires(B& b) { b.update(0, 0.0); },
                  "a Bandit needs `void update(int arm, double reward)` to record the outcome of one pull");
    static_assert(requires(B& b) { b.sync(); },
                  "a Bandit needs `void sync()` to fold the recorded outcomes into its choice policy");
    static_assert(requires(const B& b) { { b.sync_interval() } -> std::convertible_to<int>; },
                  "a Bandit needs `int sync_interval() const`: the number of pulls between syncs");
    static_assert(requires(const B& b) { { b.weights() } -> std::convertible_to<std::vector<double>>; },
                  "a Bandit needs `std::vector<double> weights() const`: its current choice probabilities");
    return Bandit<B>;
}

namespace detail {

// Shared machinery: the choice distribution in force (set at sync), the outcomes recorded
// since the last sync, and the totals folded in so far.
class BanditBase {
public:
    int arms() const { return int(probs_.size()); }
    int sync_interval() const { return sync_interval_; }

    // One uniform draw, inverted through the cumulative distribution fixed at the last sync.
    int choose(CounterRng& rng) const {
        const double u = rng.uniform();
        return int(std::upper_bound(cdf_.begin(), cdf_.end(), u) - cdf_.begin());
    }
    std::vector<double> weights() const { return probs_; }

    // Pulls and summed rewards per arm, folded in at the syncs so far (for reports and
    // for the reference's pre-process selection).
    const std::vector<std::int64_t>& pulls() const { return pulls_; }
    const std::vector<double>& total_rewards() const { return rewards_; }

    void update(int arm, double reward) { record(arm, reward); }

protected:
    BanditBase(int arms, int sync_interval, std::string_view who) {
        if (arms < 1 || arms > 1 << 20)
            throw InputError(std::string(who) + ": arms must be in [1, 2^20], got " + std::to_string(arms));
        if (sync_interval < 1)
            throw InputError(std::string(who) + ": sync_interval must be >= 1, got " + std::to_string(sync_interval));
        sync_interval_ = sync_interval;
        const auto k = std::size_t(arms);
        probs_.assign(k, 1.0 / arms);
        cdf_.assign(k, 0.0);
        batch_rewards_.assign(k, 0.0);
        batch_pulls_.assign(k, 0);
        rewards_.assign(k, 0.0);
        pulls_.assign(k, 0);
        set_probabilities(probs_);
    }

    // Checks one outcome and returns the reward that counts: a move that made the error
    // worse earns nothing (an accepted uphill move is the annealer's business, not
    // evidence for its kernel).
    double checked(int arm, double reward) const {
        if (arm < 0 || arm >= arms())
            throw InputError("bandit update: arm " + std::to_string(arm) + " is outside [0, " +
                             std::to_string(arms()) + ")");
        if (std::isnan(reward) || std::isinf(reward)) {
            std::ostringstream m;
            m << "bandit update: reward of arm " << arm << " must be finite, got " << reward;
            throw InputError(m.str());
        }
        return reward > 0 ? reward : 0.0;
    }
    void record(int arm, double reward) {
        const double r = checked(arm, reward);
        batch_rewards_[std::size_t(arm)] += r;
        batch_pulls_[std::size_t(arm)] += 1;
    }
    // Adds the batch to the totals and empties it.
    void fold_batch() {
        for (std::size_t k = 0; k < probs_.size(); ++k) {
            rewards_[k] += batch_rewards_[k];
            pulls_[k] += batch_pulls_[k];
            batch_rewards_[k] = 0;
            batch_pulls_[k] = 0;
        }
    }
    // `p`: non-negative, not all zero; normalised here.
    void set_probabilities(const std::vector<double>& p) {
        const double sum = std::accumulate(p.begin(), p.end(), 0.0);
        double c = 0;
        std::size_t last = 0;
        for (std::size_t k = 0; k < p.size(); ++k) {
            probs_[k] = p[k] / sum;
            c += probs_[k];
            cdf_[k] = c;
            if (probs_[k] > 0) last = k;
        }
        // Rounding must not leave a sliver above the last possible arm, nor let an arm
        // of probability zero be drawn.
        for (std::size_t k = last; k < p.size(); ++k) cdf_[k] = 1.0;
    }

    std::vector<double> batch_rewards_;
    std::vector<std::int64_t> batch_pulls_;
    std::vector<double> rewards_;
    std::vector<std::int64_t> pulls_;

private:
    int sync_interval_ = 64;
    std::vector<double> probs_;
    std::vector<double> cdf_;
};

// ε-greedy over an index: (1 - ε) split evenly among the arms sharing the top index
// (all untried arms tie at +∞), ε spread over all arms.
inline void epsilon_greedy(const std::vector<double>& index, double epsilon, std::vector<double>& p) {
    const double top = *std::max_element(index.begin(), index.end());
    const auto ties = std::count(index.begin(), index.end(), top);
    const double k = double(index.size());
    for (std::size_t a = 0; a < index.size(); ++a)
        p[a] = epsilon / k + (index[a] == top ? (1 - epsilon) / double(ties) : 0.0);
}

inline void check_epsilon(double epsilon, std::string_view who) {
    if (!(epsilon >= 0 && epsilon <= 1)) {
        std::ostringstream m;
        m << who << ": epsilon must be in [0, 1], got " << epsilon;
        throw InputError(m.str());
    }
}
inline void check_exploration(double c, std::string_view who) {
    if (!(c >= 0) || !std::isfinite(c)) {
        std::ostringstream m;
        m << who << ": exploration constant c must be >= 0 and finite, got " << c;
        throw InputError(m.str());
    }
}

}  // namespace detail

// Every arm equally likely: the reference's basic randomisation (§4.3.1), and the
// baseline every other policy must beat. Outcomes are recorded for reports only.
class UniformBandit : public detail::BanditBase {
public:
    explicit UniformBandit(int arms, int sync_interval = 64) : BanditBase(arms, sync_interval, "UniformBandit") {}
    void sync() { fold_batch(); }
};

// The reference's history-based decision strategy (§4.3.2).
//
// Run time: a table holds, per arm, the reward and the number of pulls, both decayed by
// `decay` at every sync (a memory of about sync_interval / (1 - decay) pulls), because the
// kernel that pays changes as the surface converges and the temperature falls. At each
// sync the choice probabilities become
//     p_k = floor + (1 - arms · floor) · rate_k / Σ rate,   rate_k = reward_k / pulls_k,
// with floor = floor_fraction / arms. The table ranks kernels by reward per pull, not by
// accumulated reward: an arm that is chosen more often gathers more reward whatever it is
// worth, so raw sums would reinforce the table's own past choices instead of measuring
// the kernels. The floor is the reference's remedy against shapes whose probability
// decays to zero and can then never prove themselves again; with the default
// floor_fraction = 0.25 every arm is tried at least a quarter as often as under uniform
// choice. Arms not tried yet are given the best observed rate (optimism), and until any
// reward has been seen the choice is uniform. Updates reach the probabilities only at a
// sync (the reference's batchSize), so one lucky move cannot swing the table.
//
// Pre-process: run a short phase over a large bank, then keep the arms that earned the
// most with preselect() and continue with subset() (or a fresh HistoryBandit) over those.
class HistoryBandit : public detail::BanditBase {
public:
    struct Params {
        double floor_fraction = 0.25;  // share of the choices spread uniformly, in [0, 1]
        double decay = 0.95;           // per sync, in (0, 1]; 1 keeps the whole history
        int sync_interval = 64;
    };

    explicit HistoryBandit(int arms) : HistoryBandit(arms, Params{}) {}
    HistoryBandit(int arms, const Params& params)
        : BanditBase(arms, params.sync_interval, "HistoryBandit"), params_(params) {
        if (!(params.floor_fraction >= 0 && params.floor_fraction <= 1)) {
            std::ostringstream m;
            m << "HistoryBandit: floor_fraction must be in [0, 1], got " << params.floor_fraction;
            throw InputError(m.str());
        }
        if (!(params.decay > 0 && params.decay <= 1)) {
            std::ostringstream m;
            m << "HistoryBandit: decay must be in (0, 1], got " << params.decay;
            throw InputError(m.str());
        }
        table_rewards_.assign(std::size_t(arms), 0.0);
        table_pulls_.assign(std::size_t(arms), 0.0);
        scratch_.assign(std::size_t(arms), 0.0);
        recompute();
    }

    const Params& params() const { return params_; }
    double floor() const { return params_.floor_fraction / arms(); }

    void sync() {
        for (std::size_t k = 0; k < table_rewards_.size(); ++k) {
            table_rewards_[k] = params_.decay * table_rewards_[k] + batch_rewards_[k];
            table_pulls_[k] = params_.decay * table_pulls_[k] + double(batch_pulls_[k]);
        }
        fold_batch();
        recompute();
    }

    // Reward per pull of each arm as of the last sync (0 for arms never tried).
    std::vector<double> rates() const {
        std::vector<double> r(table_rewards_.size(), 0.0);
        for (std::size_t k = 0; k < r.size(); ++k)
            if (table_pulls_[k] > 0) r[k] = table_rewards_[k] / table_pulls_[k];
        return r;
    }

    // Pre-process selection: the indices of the `keep` arms with the largest rewards,
    // best first (ties keep the lower index first).
    static std::vector<int> preselect(const std::vector<double>& reward_per_arm, int keep) {
        const int n = int(reward_per_arm.size());
        if (keep < 1 || keep > n)
            throw InputError("HistoryBandit::preselect: keep must be in [1, " + std::to_string(n) + "], got " +
                             std::to_string(keep));
        for (int k = 0; k < n; ++k)
            if (!std::isfinite(reward_per_arm[std::size_t(k)]))
                throw InputError("HistoryBandit::preselect: reward of arm " + std::to_string(k) + " is not finite");
        std::vector<int> order(static_cast<std::size_t>(n));
        std::iota(order.begin(), order.end(), 0);
        std::stable_sort(order.begin(), order.end(), [&](int a, int b) {
            return reward_per_arm[std::size_t(a)] > reward_per_arm[std::size_t(b)];
        });
        order.resize(std::size_t(keep));
        return order;
    }

    // A bandit over the arms `kept` (new arm k is old arm kept[k]) that starts from their
    // rows of this table, with the same parameters. Pending updates are not carried over.
    HistoryBandit subset(const std::vector<int>& kept) const {
        if (kept.empty()) throw InputError("HistoryBandit::subset: no arms kept");
        HistoryBandit b(int(kept.size()), params_);
        for (std::size_t k = 0; k < kept.size(); ++k) {
            const int a = kept[k];
            if (a < 0 || a >= arms())
                throw InputError("HistoryBandit::subset: arm " + std::to_string(a) + " is outside [0, " +
                                 std::to_string(arms()) + ")");
            if (std::find(kept.begin(), kept.begin() + std::ptrdiff_t(k), a) != kept.begin() + std::ptrdiff_t(k))
                throw InputError("HistoryBandit::subset: arm " + std::to_string(a) + " is kept twice");
            b.table_rewards_[k] = table_rewards_[std::size_t(a)];
            b.table_pulls_[k] = table_pulls_[std::size_t(a)];
        }
        b.recompute();
        return b;
    }

private:
    void recompute() {
        double best = 0, sum = 0;
        for (std::size_t k = 0; k < scratch_.size(); ++k)
            if (table_pulls_[k] > 0) best = std::max(best, table_rewards_[k] / table_pulls_[k]);
        for (std::size_t k = 0; k < scratch_.size(); ++k) {
            scratch_[k] = table_pulls_[k] > 0 ? table_rewards_[k] / table_pulls_[k] : best;
            sum += scratch_[k];
        }
        if (!(sum > 0)) {  // nothing earned yet: no evidence to prefer any arm
            std::fill(scratch_.begin(), scratch_.end(), 1.0);
        } else {
            const double lo = floor(), share = 1 - params_.floor_fraction;
            for (auto& p : scratch_) p = lo + share * (p / sum);
        }
        set_probabilities(scratch_);
    }

    Params params_;
    std::vector<double> table_rewards_;
    std::vector<double> table_pulls_;
    std::vector<double> scratch_;
};

// UCB1 (Auer, Cesa-Bianchi & Fischer, 2002), batched.
//
// At each sync, with n pulls in all and n_i of arm i, every arm gets the index
//     mean_i / scale + c · sqrt(2 ln n / n_i),     untried arms +∞,
// where scale is the largest mean over the tried arms. UCB1 assumes rewards in [0, 1];
// error decreases have no fixed scale and shrink as the annealing cools, and a single
// outlier would make a running maximum of rewards squash every mean to nothing, so the
// means are measured against the best arm instead: the constant c keeps its meaning on
// any problem. Between syncs the policy is ε-greedy on the index: the arms with the top
// index share 1 - ε (the untried ones at first, so every arm is tried in the first
// batch), and ε is spread over all arms, which keeps every estimate alive while a batch
// of sync_interval pulls is drawn from one distribution. The statistics are never
// forgotten: for a reward landscape that drifts, use DiscountedUcbBandit.
class Ucb1Bandit : public detail::BanditBase {
public:
    struct Params {
        double c = 1.0;         // exploration constant, >= 0
        double epsilon = 0.1;   // share of uniform choices between syncs, in [0, 1]
        int sync_interval = 64;
    };

    explicit Ucb1Bandit(int arms) : Ucb1Bandit(arms, Params{}) {}
    Ucb1Bandit(int arms, const Params& params) : BanditBase(arms, params.sync_interval, "Ucb1Bandit"), params_(params) {
        detail::check_exploration(params.c, "Ucb1Bandit");
        detail::check_epsilon(params.epsilon, "Ucb1Bandit");
        index_.assign(std::size_t(arms), std::numeric_limits<double>::infinity());
        scratch_.assign(std::size_t(arms), 0.0);
        recompute();
    }

    const Params& params() const { return params_; }
    // The UCB1 indices computed at the last sync (+∞ for untried arms).
    const std::vector<double>& indices() const { return index_; }

    void sync() {
        fold_batch();
        recompute();
    }

private:
    void recompute() {
        std::int64_t n = 0;
        double scale = 0;
        for (std::size_t k = 0; k < index_.size(); ++k) {
            n += pulls_[k];
            if (pulls_[k] > 0) scale = std::max(scale, rewards_[k] / double(pulls_[k]));
        }
        if (!(scale > 0)) scale = 1;
        for (std::size_t k = 0; k < index_.size(); ++k)
            index_[k] = pulls_[k] == 0 ? std::numeric_limits<double>::infinity()
                                       : rewards_[k] / double(pulls_[k]) / scale +
                                             params_.c * std::sqrt(2 * std::log(double(n)) / double(pulls_[k]));
        detail::epsilon_greedy(index_, params_.epsilon, scratch_);
        set_probabilities(scratch_);
    }

    Params params_;
    std::vector<double> index_;
    std::vector<double> scratch_;
};

// Discounted UCB (Garivier & Moulines, 2011), batched: UCB for rewards that drift.
//
// The kernel that pays best changes during a run (big smooth kernels early, narrow or
// anisotropic ones once the coarse shape is right), so old evidence should fade. Every
// pull multiplies all past counts and rewards by gamma, so the statistics cover roughly
// the last 1 / (1 - gamma) pulls (1000 by default: about 16 batches, yet short next to a
// run). At each sync, with N_i the discounted pulls of arm i and n = Σ N_i,
//     index_i = mean_i / scale + c · sqrt(2 ln max(n, 1) / N_i),   never-pulled arms +∞,
// with means scaled by the best arm's mean as in Ucb1Bandit. An arm left alone sees N_i
// shrink and its bonus grow until it is tried again: that is how a change is noticed.
// Between syncs the policy is ε-greedy on the index, as in Ucb1Bandit. The discounting
// happens in update(), but the policy still changes only at sync().
// The default c = 0.5 is half UCB1's: the counts never grow beyond the memory, so the
// full bonus keeps handing whole batches to arms that the ε share already samples. On
// Bernoulli test problems (5 arms, batches of 64) c = 1 spent about a quarter of the
// batches that way, c = 0.5 well under a tenth, with the same recovery after a change.
class DiscountedUcbBandit : public detail::BanditBase {
public:
    struct Params {
        double gamma = 0.999;   // discount per pull, in (0, 1]
        double c = 0.5;         // exploration constant, >= 0
        double epsilon = 0.1;   // share of uniform choices between syncs, in [0, 1]
        int sync_interval = 64;
    };

    explicit DiscountedUcbBandit(int arms) : DiscountedUcbBandit(arms, Params{}) {}
    DiscountedUcbBandit(int arms, const Params& params)
        : BanditBase(arms, params.sync_interval, "DiscountedUcbBandit"), params_(params) {
        if (!(params.gamma > 0 && params.gamma <= 1)) {
            std::ostringstream m;
            m << "DiscountedUcbBandit: gamma must be in (0, 1], got " << params.gamma;
            throw InputError(m.str());
        }
        detail::check_exploration(params.c, "DiscountedUcbBandit");
        detail::check_epsilon(params.epsilon, "DiscountedUcbBandit");
        disc_rewards_.assign(std::size_t(arms), 0.0);
        disc_pulls_.assign(std::size_t(arms), 0.0);
        index_.assign(std::size_t(arms), std::numeric_limits<double>::infinity());
        scratch_.assign(std::size_t(arms), 0.0);
        recompute();
    }

    const Params& params() const { return params_; }
    const std::vector<double>& indices() const { return index_; }

    void update(int arm, double reward) {
        const double r = checked(arm, reward);
        for (std::size_t k = 0; k < disc_pulls_.size(); ++k) {
            disc_rewards_[k] *= params_.gamma;
            disc_pulls_[k] *= params_.gamma;
        }
        disc_rewards_[std::size_t(arm)] += r;
        disc_pulls_[std::size_t(arm)] += 1;
        record(arm, r);
    }

    void sync() {
        fold_batch();
        recompute();
    }

private:
    void recompute() {
        double n = 0, scale = 0;
        for (std::size_t k = 0; k < index_.size(); ++k) {
            n += disc_pulls_[k];
            if (pulls_[k] > 0 && disc_pulls_[k] > 0) scale = std::max(scale, disc_rewards_[k] / disc_pulls_[k]);
        }
        if (!(scale > 0)) scale = 1;
        const double log_n = std::log(std::max(n, 1.0));
        for (std::size_t k = 0; k < index_.size(); ++k) {
            // An arm pulled so long ago that its count underflowed counts as never pulled.
            index_[k] = !(disc_pulls_[k] > 0) ? std::numeric_limits<double>::infinity()
                                              : disc_rewards_[k] / disc_pulls_[k] / scale +
                                                    params_.c * std::sqrt(2 * log_n / disc_pulls_[k]);
        }
        detail::epsilon_greedy(index_, params_.epsilon, scratch_);
        set_probabilities(scratch_);
    }

    Params params_;
    std::vector<double> disc_rewards_;
    std::vector<double> disc_pulls_;
    std::vector<double> index_;
    std::vector<double> scratch_;
};

// One of the bandits above, chosen at run time (e.g. from a command-line option).
class AnyBandit {
public:
    using Variant = std::variant<UniformBandit, HistoryBandit, Ucb1Bandit, DiscountedUcbBandit>;

    template <class B>
        requires std::is_constructible_v<Variant, B&&>
    AnyBandit(B&& b) : v_(std::forward<B>(b)) {}  // NOLINT: implicit on purpose

    int arms() const { return std::visit([](const auto& b) { return b.arms(); }, v_); }
    int choose(CounterRng& rng) const { return std::visit([&](const auto& b) { return b.choose(rng); }, v_); }
    void update(int arm, double reward) { std::visit([&](auto& b) { b.update(arm, reward); }, v_); }
    void sync() { std::visit([](auto& b) { b.sync(); }, v_); }
    int sync_interval() const { return std::visit([](const auto& b) { return b.sync_interval(); }, v_); }
    std::vector<double> weights() const { return std::visit([](const auto& b) { return b.weights(); }, v_); }
    const std::vector<std::int64_t>& pulls() const {
        return std::visit([](const auto& b) -> const std::vector<std::int64_t>& { return b.pulls(); }, v_);
    }
    const std::vector<double>& total_rewards() const {
        return std::visit([](const auto& b) -> const std::vector<double>& { return b.total_rewards(); }, v_);
    }
    const Variant& variant() const { return v_; }
    Variant& variant() { return v_; }

private:
    Variant v_;
};

// A bandit of the given kind with default parameters.
inline AnyBandit make_bandit(BanditKind kind, int arms, int sync_interval = 64) {
    switch (kind) {
        case BanditKind::uniform: return UniformBandit(arms, sync_interval);
        case BanditKind::history: return HistoryBandit(arms, {.sync_interval = sync_interval});
        case BanditKind::ucb1: return Ucb1Bandit(arms, {.sync_interval = sync_interval});
        case BanditKind::discounted_ucb: return DiscountedUcbBandit(arms, {.sync_interval = sync_interval});
    }
    throw InputError("unknown bandit kind " + std::to_string(int(kind)));
}

static_assert(check_bandit<UniformBandit>());
static_assert(check_bandit<HistoryBandit>());
static_assert(check_bandit<Ucb1Bandit>());
static_assert(check_bandit<DiscountedUcbBandit>());
static_assert(check_bandit<AnyBandit>());

}  // namespace freeform
