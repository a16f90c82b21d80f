// TaskPool (core/task_pool.hpp), the workers of the annealer's speculative windows: every
// index runs exactly once per run, runs back to back and after the workers fell asleep
// lose nothing, the work really is shared between threads, and pools start and stop
// cleanly. ThreadSanitizer, where a build has it, watches the same cases.
#include <doctest/doctest.h>

#include <atomic>
#include <chrono>
#include <set>
#include <mutex>
#include <thread>
#include <vector>

#include <freeform/core/task_pool.hpp>

using freeform::TaskPool;

TEST_CASE("TaskPool: every index exactly once, for any size and thread count") {
    for (int threads : {1, 2, 3, 8}) {
        TaskPool pool(threads);
        CHECK(pool.threads() == threads);
        for (int n : {0, 1, 2, 3, 17, 1000}) {
            std::vector<std::atomic<int>> calls(std::size_t(std::max(n, 1)));
            pool.run(n, [&](int k) { calls[std::size_t(k)].fetch_add(1); });
            int wrong = 0;
            for (int k = 0; k < n; ++k) wrong += calls[std::size_t(k)].load() != 1;
            INFO("threads " << threads << ", n " << n);
            CHECK(wrong == 0);
        }
    }
}

TEST_CASE("TaskPool: thousands of runs back to back, and runs after the workers slept") {
    TaskPool pool(4);
    std::atomic<long long> sum{0};
    long long expected = 0;
    for (int run = 0; run < 5000; ++run) {
        const int n = 1 + run % 7;
        pool.run(n, [&](int k) { sum.fetch_add(k + 1); });
        expected += n * (n + 1) / 2;
    }
    CHECK(sum.load() == expected);
    // Idle workers spin about a millisecond and then sleep on the condition variable: a
    // run after a pause must wake them (or be done by the caller) all the same.
    for (int run = 0; run < 5; ++run) {
        std::this_thread::sleep_for(std::chrono::milliseconds(20));
        std::atomic<int> count{0};
        pool.run(64, [&](int) { count.fetch_add(1); });
        CHECK(count.load() == 64);
    }
}

TEST_CASE("TaskPool: the work is shared (a task waits for one on another thread)") {
    TaskPool pool(2);
    std::mutex m;
    std::set<std::thread::id> ids;
    std::atomic<bool> other_started{false};
    const std::thread::id caller = std::this_thread::get_id();
    bool waited_out = false;
    pool.run(2, [&](int) {
        {
            std::lock_guard lock(m);
            ids.insert(std::this_thread::get_id());
        }
        if (std::this_thread::get_id() != caller) {
            other_started.store(true);
            return;
        }
        // The caller's task holds on until a worker has taken the other index: a pool that
        // ran serially would leave it waiting (5 s, then the check fails).
        const auto until = std::chrono::steady_clock::now() + std::chrono::seconds(5);
        while (!other_started.load() && std::chrono::steady_clock::now() < until) std::this_thread::yield();
        waited_out = !other_started.load();
    });
    // The caller takes one index and the worker the other, unless the worker took both
    // (then the caller ran none, which is fine too: the work was still shared).
    CHECK(!waited_out);
    CHECK(ids.size() >= 1);
    CHECK((ids.size() == 2 || ids.count(caller) == 0));
}

TEST_CASE("TaskPool: pools start and stop cleanly, idle or just used") {
    for (int k = 0; k < 50; ++k) {
        TaskPool pool(1 + k % 4);
        if (k % 2) {
            std::atomic<int> count{0};
            pool.run(10, [&](int) { count.fetch_add(1); });
            CHECK(count.load() == 10);
        }
    }
}
