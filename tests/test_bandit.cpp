// Kernel choice as a multi-armed bandit: each policy against synthetic Bernoulli rewards,
// the batching contract (choices fixed between syncs), floors, determinism, errors.
#include <doctest/doctest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <functional>
#include <numeric>
#include <vector>

#include <freeform/propose/bandit.hpp>

using namespace freeform;

namespace {

const std::vector<double> stationary_p = {0.1, 0.2, 0.7, 0.3, 0.15};

// Plays `pulls` rounds; arm k pays 1 with probability p(t)[k]. Choices and rewards use
// separate counter-based streams so that they do not depend on each other's draws.
template <Bandit B>
std::vector<std::int64_t> play(B& b, int pulls, const std::function<const std::vector<double>&(int)>& p,
                               std::uint64_t seed = 1, const std::function<void(const B&)>& after_sync = {}) {
    CounterRng choice(seed, 1), payoff(seed, 2);
    std::vector<std::int64_t> count(std::size_t(b.arms()), 0);
    for (int t = 0; t < pulls; ++t) {
        const int arm = b.choose(choice);
        REQUIRE(arm >= 0);
        REQUIRE(arm < b.arms());
        ++count[std::size_t(arm)];
        b.update(arm, payoff.uniform() < p(t)[std::size_t(arm)] ? 1.0 : 0.0);
        if ((t + 1) % b.sync_interval() == 0) {
            b.sync();
            if (after_sync) after_sync(b);
        }
    }
    return count;
}

template <Bandit B>
std::vector<std::int64_t> play_stationary(B& b, int pulls, std::uint64_t seed = 1) {
    return play<B>(b, pulls, [](int) -> const std::vector<double>& { return stationary_p; }, seed);
}

template <class V>
int argmax(const V& v) {
    return int(std::max_element(v.begin(), v.end()) - v.begin());
}

double sum(const std::vector<double>& v) { return std::accumulate(v.begin(), v.end(), 0.0); }

}  // namespace

static_assert(!Bandit<int>);
static_assert(Bandit<AnyBandit>);

TEST_CASE("UniformBandit: equal weights whatever the rewards") {
    UniformBandit b(5);
    CHECK(b.arms() == 5);
    CHECK(b.sync_interval() == 64);
    const auto count = play_stationary(b, 20000);
    for (double w : b.weights()) CHECK(w == doctest::Approx(0.2));
    for (auto c : count) CHECK(c == doctest::Approx(4000).epsilon(0.06));
    CHECK(std::accumulate(b.pulls().begin(), b.pulls().end(), std::int64_t(0)) == 20000 / 64 * 64);
}

TEST_CASE_TEMPLATE("a learning bandit favours the best arm of a stationary problem", B, HistoryBandit, Ucb1Bandit,
                   DiscountedUcbBandit) {
    for (std::uint64_t seed : {1u, 2u, 3u}) {
        B b(5);
        const auto count = play_stationary(b, 20000, seed);
        const auto w = b.weights();
        CHECK(sum(w) == doctest::Approx(1.0));
        CHECK(argmax(w) == 2);
        CHECK(argmax(count) == 2);
        CHECK(count[2] > 20000 / 5);  // better than uniform choice
        CHECK(argmax(b.total_rewards()) == 2);
    }
}

TEST_CASE("make_bandit builds every named bandit, and each learns through AnyBandit") {
    for (const auto& n : bandit_kind_names) {
        const std::string_view name = n.name;
        AnyBandit b = make_bandit(n.value, 5, 32);
        CHECK(b.arms() == 5);
        CHECK(b.sync_interval() == 32);
        const auto count = play_stationary(b, 20000);
        if (name == "uniform") continue;
        CHECK(argmax(b.weights()) == 2);
        CHECK(argmax(count) == 2);
    }
    CHECK(std::holds_alternative<Ucb1Bandit>(make_bandit(BanditKind::ucb1, 3).variant()));
    // A bandit's name is read at the file boundary only (io/scene_json.hpp; test_scene_json
    // checks that an unknown one is refused, naming the key).
}

TEST_CASE("HistoryBandit: probabilities follow reward per pull and never drop below the floor") {
    // Arm 0 never pays: the floor is all that keeps it alive.
    const std::vector<double> p = {0.0, 0.2, 0.7, 0.3, 0.15};
    for (double floor_fraction : {0.25, 0.05, 0.0}) {
        HistoryBandit b(5, {.floor_fraction = floor_fraction, .decay = 0.95, .sync_interval = 64});
        CHECK(b.floor() == doctest::Approx(floor_fraction / 5));
        double lowest = 1;
        const auto count = play<HistoryBandit>(
            b, 20000, [&](int) -> const std::vector<double>& { return p; }, 5,
            [&](const HistoryBandit& h) {
                const auto w = h.weights();
                CHECK(sum(w) == doctest::Approx(1.0));
                lowest = std::min(lowest, *std::min_element(w.begin(), w.end()));
            });
        CHECK(lowest >= b.floor() * (1 - 1e-12));
        CHECK(b.weights()[0] == doctest::Approx(b.floor()));
        if (floor_fraction > 0) CHECK(count[0] > 0);
        // Reward per pull is measured, not accumulated reward: the estimates match p.
        const auto rate = b.rates();
        CHECK(rate[2] == doctest::Approx(0.7).epsilon(0.1));
        CHECK(rate[0] == 0.0);
        // p_k = floor + (1 - floor_fraction) rate_k / Σ rate.
        const double total = sum(rate);
        for (std::size_t k = 0; k < 5; ++k)
            CHECK(b.weights()[k] == doctest::Approx(b.floor() + (1 - floor_fraction) * rate[k] / total));
    }
}

TEST_CASE("HistoryBandit: uniform until a reward is seen; untried arms are given the best rate") {
    HistoryBandit b(4);
    for (double w : b.weights()) CHECK(w == 0.25);
    b.update(1, 0.0);
    b.sync();
    for (double w : b.weights()) CHECK(w == 0.25);
    b.update(1, 2.0);  // arm 1: 2 / 2 pulls
    b.update(3, 0.0);  // arm 3: nothing
    b.sync();
    const auto w = b.weights();
    CHECK(w[0] == doctest::Approx(w[1]));
    CHECK(w[2] == doctest::Approx(w[1]));
    CHECK(w[3] == doctest::Approx(b.floor()));
    CHECK(w[1] > w[3]);
}

TEST_CASE("HistoryBandit pre-process: preselect keeps the best arms, subset carries their history") {
    CHECK(HistoryBandit::preselect({0.3, 0.9, 0.1, 0.9, 0.5}, 3) == std::vector<int>{1, 3, 4});
    CHECK(HistoryBandit::preselect({0.3, 0.9, 0.1}, 1) == std::vector<int>{1});
    CHECK(HistoryBandit::preselect({0.3, 0.9, 0.1}, 3) == std::vector<int>{1, 0, 2});
    CHECK_THROWS_WITH_AS(HistoryBandit::preselect({0.3, 0.9}, 0), doctest::Contains("keep"), InputError);
    CHECK_THROWS_WITH_AS(HistoryBandit::preselect({0.3, 0.9}, 3), doctest::Contains("keep"), InputError);
    CHECK_THROWS_AS(HistoryBandit::preselect({0.3, std::nan("")}, 1), InputError);

    // A short pre-process over the whole bank, then the main phase over the best three.
    HistoryBandit pre(5);
    play_stationary(pre, 3000, 4);
    const auto kept = HistoryBandit::preselect(pre.total_rewards(), 3);
    CHECK(kept[0] == 2);
    CHECK(std::find(kept.begin(), kept.end(), 3) != kept.end());
    const HistoryBandit main = pre.subset(kept);
    CHECK(main.arms() == 3);
    const auto rate = pre.rates();
    for (std::size_t k = 0; k < 3; ++k) CHECK(main.rates()[k] == rate[std::size_t(kept[k])]);
    CHECK(argmax(main.weights()) == 0);
    CHECK_THROWS_AS(pre.subset({}), InputError);
    CHECK_THROWS_WITH_AS(pre.subset({0, 5}), doctest::Contains("arm 5"), InputError);
    CHECK_THROWS_WITH_AS(pre.subset({1, 1}), doctest::Contains("twice"), InputError);
}

TEST_CASE("Ucb1Bandit: untried arms first, then greedy on the index with epsilon exploration") {
    Ucb1Bandit b(4, {.c = 1.0, .epsilon = 0.2, .sync_interval = 8});
    for (double w : b.weights()) CHECK(w == 0.25);
    b.update(0, 1.0);
    b.sync();
    // Arms 1..3 are untried and share the greedy share; arm 0 keeps only its epsilon part.
    CHECK(b.weights()[0] == doctest::Approx(0.05));
    for (int k = 1; k < 4; ++k) CHECK(b.weights()[std::size_t(k)] == doctest::Approx(0.05 + 0.8 / 3));
    b.update(1, 0.0);
    b.update(2, 0.5);
    b.update(3, 0.0);
    b.sync();
    // Each arm pulled once: indices differ only by the scaled means 1, 0, 0.5, 0.
    const auto& idx = b.indices();
    const double bonus = std::sqrt(2 * std::log(4.0));
    CHECK(idx[0] == doctest::Approx(1.0 + bonus));
    CHECK(idx[2] == doctest::Approx(0.5 + bonus));
    CHECK(b.weights()[0] == doctest::Approx(0.85));
    CHECK(sum(b.weights()) == doctest::Approx(1.0));

    // With no exploration the choice is the argmax alone: choose() never returns another arm.
    Ucb1Bandit greedy(3, {.c = 0.5, .epsilon = 0.0, .sync_interval = 64});
    greedy.update(0, 0.1);
    greedy.update(1, 0.9);
    greedy.update(2, 0.2);
    greedy.sync();
    CounterRng rng(3);
    for (int t = 0; t < 1000; ++t) CHECK(greedy.choose(rng) == 1);
}

TEST_CASE("DiscountedUcbBandit recovers when the best arm changes mid-run") {
    const std::vector<double> after = {0.1, 0.2, 0.15, 0.3, 0.7};  // arm 4 becomes the best
    const int pulls = 20000;
    const auto p = [&](int t) -> const std::vector<double>& { return t < pulls / 2 ? stationary_p : after; };
    DiscountedUcbBandit b(5);
    std::vector<double> mid;
    std::vector<std::int64_t> late(5, 0);
    int seen = 0;
    play<DiscountedUcbBandit>(b, pulls, p, 9, [&](const DiscountedUcbBandit& d) {
        seen += d.sync_interval();
        if (seen == pulls / 2 / 64 * 64) mid = d.weights();
    });
    REQUIRE(mid.size() == 5);
    CHECK(argmax(mid) == 2);
    CHECK(argmax(b.weights()) == 4);
    CHECK(b.weights()[4] > 0.5);

    // The history table with decay also follows the change (more slowly).
    HistoryBandit h(5, {.floor_fraction = 0.25, .decay = 0.9, .sync_interval = 64});
    play<HistoryBandit>(h, pulls, p, 9);
    CHECK(argmax(h.weights()) == 4);
}

TEST_CASE_TEMPLATE("choices depend only on the state at the last sync and on the random numbers", B, UniformBandit,
                   HistoryBandit, Ucb1Bandit, DiscountedUcbBandit) {
    B b(5);
    play_stationary(b, 640, 11);  // some history, ends on a sync
    const auto w = b.weights();
    CounterRng r1(42);
    std::vector<int> before(500);
    for (int& c : before) c = b.choose(r1);
    // Many outcomes recorded, no sync: nothing visible changes.
    CounterRng payoff(5, 5);
    for (int t = 0; t < 5000; ++t) b.update(int(payoff.below(5)), payoff.uniform() < 0.5 ? 0.0 : 3.0);
    CHECK(b.weights() == w);
    CounterRng r2(42);
    for (int c : before) CHECK(b.choose(r2) == c);
    // The sync folds them in.
    b.sync();
    if constexpr (!std::is_same_v<B, UniformBandit>) CHECK(b.weights() != w);
}

TEST_CASE_TEMPLATE("bandits are deterministic given the seed", B, UniformBandit, HistoryBandit, Ucb1Bandit,
                   DiscountedUcbBandit) {
    const auto trace = [](std::uint64_t seed) {
        B b(5);
        CounterRng choice(seed, 1), payoff(seed, 2);
        std::vector<int> arms;
        for (int t = 0; t < 3000; ++t) {
            const int a = b.choose(choice);
            arms.push_back(a);
            b.update(a, payoff.uniform() < stationary_p[std::size_t(a)] ? 1.0 : 0.0);
            if ((t + 1) % b.sync_interval() == 0) b.sync();
        }
        return std::make_pair(arms, b.weights());
    };
    const auto a = trace(17), b = trace(17), c = trace(18);
    CHECK(a.first == b.first);
    CHECK(a.second == b.second);
    CHECK(a.first != c.first);
}

TEST_CASE("every choose() draws exactly one random number") {
    HistoryBandit b(5);
    play_stationary(b, 640);
    CounterRng r(8), shadow(8);
    for (int t = 0; t < 100; ++t) {
        b.choose(r);
        shadow.uniform();
    }
    CHECK(r.next_u64() == shadow.next_u64());
}

TEST_CASE("bad bandit parameters and outcomes throw InputError naming them") {
    CHECK_THROWS_WITH_AS(UniformBandit(0), doctest::Contains("arms"), InputError);
    CHECK_THROWS_WITH_AS(UniformBandit(3, 0), doctest::Contains("sync_interval"), InputError);
    CHECK_THROWS_WITH_AS(HistoryBandit(3, {.floor_fraction = 1.5}), doctest::Contains("floor_fraction"), InputError);
    CHECK_THROWS_WITH_AS(HistoryBandit(3, {.decay = 0.0}), doctest::Contains("decay"), InputError);
    CHECK_THROWS_WITH_AS(Ucb1Bandit(3, {.c = -1.0}), doctest::Contains("exploration constant"), InputError);
    CHECK_THROWS_WITH_AS(Ucb1Bandit(3, {.epsilon = 2.0}), doctest::Contains("epsilon"), InputError);
    CHECK_THROWS_WITH_AS(DiscountedUcbBandit(3, {.gamma = 1.5}), doctest::Contains("gamma"), InputError);
    HistoryBandit b(3);
    CHECK_THROWS_WITH_AS(b.update(3, 1.0), doctest::Contains("arm 3"), InputError);
    CHECK_THROWS_WITH_AS(b.update(-1, 1.0), doctest::Contains("arm -1"), InputError);
    CHECK_THROWS_WITH_AS(b.update(0, std::nan("")), doctest::Contains("finite"), InputError);
    CHECK_THROWS_AS(b.update(0, HUGE_VAL), InputError);
    // A move that made the error worse earns nothing rather than a penalty.
    b.update(0, -5.0);
    b.update(1, 1.0);
    b.sync();
    CHECK(b.total_rewards()[0] == 0.0);
    CHECK(b.pulls()[0] == 1);
}
