#pragma once
// A small pool of persistent workers for short, frequent parallel sections: the
// speculative windows of the annealer, each a handful of move evaluations of tens of
// microseconds.
//
// Why not an OpenMP parallel region: libgomp's idle workers spin for a while after each
// region, and on a machine whose other core is busy (a shared CI runner, a second job)
// the spinning worker steals the time the main thread needs; a region also has to wait
// for every worker to wake up. Here the caller works too and takes whatever indices are
// still unclaimed, so a descheduled worker never holds it up unless it already started a
// task; idle workers spin only briefly (yielding their core) and then sleep on a
// condition variable.
#include <algorithm>
#include <atomic>
#include <condition_variable>
#include <mutex>
#include <cstdint>
#include <functional>
#include <thread>
#include <vector>

namespace freeform {

class TaskPool {
public:
    // `threads` in total, the caller included: threads - 1 workers are started.
    explicit TaskPool(int threads) {
        for (int k = 1; k < threads; ++k) workers_.emplace_back([this] { work(); });
    }
    TaskPool(const TaskPool&) = delete;
    TaskPool& operator=(const TaskPool&) = delete;
    ~TaskPool() {
        {
            std::lock_guard lock(mutex_);
            stop_.store(true);
            generation_.fetch_add(1);
        }
        wake_.notify_all();
        for (auto& t : workers_) t.join();
    }

    int threads() const { return int(workers_.size()) + 1; }

    // Calls task(k) once for every k in [0, n) and returns when all calls have returned
    // and no worker still looks at `task`. `task` must not throw.
    void run(int n, const std::function<void(int)>& task) {
        if (workers_.empty() || n <= 1) {
            for (int k = 0; k < n; ++k) task(k);
            return;
        }
        // Publication order matters: counters, then size, then the task, then the
        // generation that wakes the workers (all sequentially consistent).
        next_.store(0);
        done_.store(0);
        n_.store(n);
        task_.store(&task);
        {
            std::lock_guard lock(mutex_);
            generation_.fetch_add(1);
        }
        wake_.notify_all();
        claim(task, n);
        wait_for([&] { return done_.load() >= n; });
        task_.store(nullptr);
        // A worker that woke for this run may still be about to look at it.
        wait_for([&] { return active_.load() == 0; });
    }

private:
    void claim(const std::function<void(int)>& task, int n) {
        for (int k; (k = next_.fetch_add(1)) < n;) {
            task(k);
            if (done_.fetch_add(1) + 1 == n) signal_caller();
        }
    }

    void signal_caller() {
        { std::lock_guard lock(mutex_); }  // orders the change before a sleeping caller re-checks
        finished_.notify_all();
    }

    // The caller's wait: tasks are short, so spin a little, then yield the core for about
    // a millisecond (as an idle worker does), before sleeping. A caller that finished its
    // share a few microseconds before a worker used to fall asleep here and wake tens of
    // microseconds later (perf: a quarter of a split move's time with two threads).
    template <class Ready>
    void wait_for(Ready&& ready) {
        for (int spin = 0; spin < 4000; ++spin)
            if (ready()) return;
        for (int spin = 0; spin < 2000; ++spin) {
            std::this_thread::yield();
            if (ready()) return;
        }
        std::unique_lock lock(mutex_);
        finished_.wait(lock, ready);
    }

    void work() {
        // Not generation_.load(): a worker that starts late must still see the runs (and
        // the stop) published before it got to run.
        int seen = 0;
        for (;;) {
            bool woke = false;
            for (int spin = 0; spin < 2000 && !woke; ++spin) woke = generation_.load() != seen;
            // Runs often come back to back with a few tens of microseconds between them (one
            // proposal's rays split over the threads, then the caller's bookkeeping): stay
            // awake about a millisecond (2,000 yields of about 0.5 µs here), but yield the
            // core to anything else that wants it.
            for (int spin = 0; spin < 2000 && !woke; ++spin) {
                std::this_thread::yield();
                woke = generation_.load() != seen;
            }
            if (!woke) {
                std::unique_lock lock(mutex_);
                wake_.wait(lock, [&] { return generation_.load() != seen; });
            }
            active_.fetch_add(1);
            seen = generation_.load();
            const bool stop = stop_.load();
            if (!stop)
                if (const auto* task = task_.load()) claim(*task, n_.load());
            active_.fetch_sub(1);
            signal_caller();
            if (stop) return;
        }
    }

    std::vector<std::thread> workers_;
    std::mutex mutex_;
    std::condition_variable wake_;      // workers: a new run (or stop)
    std::condition_variable finished_;  // caller: tasks done, workers idle
    std::atomic<int> generation_{0};
    std::atomic<int> next_{0};
    std::atomic<int> done_{0};
    std::atomic<int> n_{0};
    std::atomic<int> active_{0};
    std::atomic<bool> stop_{false};
    std::atomic<const std::function<void(int)>*> task_{nullptr};
};

}  // namespace freeform
