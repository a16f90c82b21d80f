#pragma once
// A whole design over MPI ranks: design/pipeline.hpp's design(job, target, setup), with
// the ranks of a communicator as replicas of it or as workers on strips of it
// (replica_exchange.hpp: ReplicaMode, the coordinator, the start made once and shared).
// CMake target freeform::mpi, built only where MPI is found.
//
//     mpi::ReplicaDesign r = mpi::design(job, target, setup, MPI_COMM_WORLD);
//     if (r.design) io::write_design_outputs(...);   // rank 0 alone holds the design
//
// Every rank calls it with the same job, target and setup. Every rank plans the scene
// (so every rank finds the same input error), anneals its replica, and the best replica's
// result (replica_exchange.hpp, gather_best) is finished (smoothed, cut, traced, exported
// and judged: finish_design) on rank 0 alone. With one rank it is design() bit for bit.
// With setup.start_only rank 0 alone makes the start (the others would compute the same
// one) and no message is sent.
//
// No I/O: a caller that writes files does so on rank 0 after the call returns, so a rank
// that dies (the others then wait until the MPI runtime ends the job) leaves no partial
// output.
#include <mpi.h>

#include <cmath>
#include <cstdint>
#include <functional>
#include <optional>
#include <utility>
#include <vector>

#include <nlohmann/json.hpp>

#include "../core/exec.hpp"
#include "../design/pipeline.hpp"
#include "replica_exchange.hpp"
#if defined(__linux__)
#include <sched.h>
#endif

namespace freeform::mpi {

// Cores this process may run on: its affinity mask, which mpirun sets when it binds
// ranks (Open MPI binds each rank to one core when there are at most 2 ranks, to a
// socket beyond, and not at all when oversubscribed). 0 where it cannot be read.
inline int cores_available() {
#if defined(__linux__)
    cpu_set_t set;
    CPU_ZERO(&set);
    if (sched_getaffinity(0, sizeof set, &set) == 0) return CPU_COUNT(&set);
#endif
    return 0;
}

// Ranks x threads: the threads each rank runs and the cores it may use, in rank order.
struct RankLayout {
    std::vector<int> threads, cores;

    // The first rank with more threads than the cores it is bound to (they would take
    // turns on its cores, slower than fewer threads), or -1. A rank whose cores are
    // unknown (0) is never counted.
    int overloaded_rank() const {
        for (std::size_t r = 0; r < threads.size() && r < cores.size(); ++r)
            if (cores[r] > 0 && threads[r] > cores[r]) return int(r);
        return -1;
    }
};

// Gathers every rank's `threads` and cores_available() on rank 0 (a collective: every rank
// of `comm` calls it). The other ranks receive zeros.
inline RankLayout rank_layout(MPI_Comm comm, int threads) {
    int size = 1;
    detail::check(MPI_Comm_size(comm, &size), "MPI_Comm_size");
    const int mine[2] = {threads, cores_available()};
    std::vector<int> all(std::size_t(2 * size), 0);
    detail::check(MPI_Gather(mine, 2, MPI_INT, all.data(), 2, MPI_INT, 0, comm), "MPI_Gather");
    RankLayout l;
    for (int r = 0; r < size; ++r) {
        l.threads.push_back(all[std::size_t(2 * r)]);
        l.cores.push_back(all[std::size_t(2 * r + 1)]);
    }
    return l;
}

// How the ranks shared a design: what metrics.json's "replicas" block reports
// (replicas_json). Filled on every rank; `objectives`, `iterations_all` and `layout` on
// rank 0 only (the other ranks hold zeros there).
struct ReplicaReport {
    int ranks = 1;
    ReplicaOptions options;
    std::int64_t merges = 0;           // domains: merges of the ranks' surfaces
    std::int64_t exchange_points = 0;  // exchange points met
    std::vector<PairStats> pairs;      // tempering: swaps of each pair of neighbouring rungs
    std::vector<int> final_rungs;      // tempering: the rung each rank holds at the end
    int winner = 0;                    // the rank whose result rank 0 finished
    std::vector<double> objectives;    // every rank's final objective, in rank order
    bool judged_held_out = false;      // the objectives are the held-out ones
    std::int64_t iterations_all = 0;   // iterations of all ranks together
    RankLayout layout;                 // threads and cores of each rank
};

// What mpi::design gives each rank.
struct ReplicaDesign {
    // Rank 0: the winning replica's design, finished; the other ranks: empty.
    std::optional<CompletedDesign> design;
    // This rank's replica stopped before its budget (a progress callback asked); on rank 0
    // the winner's. With setup.start_only: false.
    bool stopped_early = false;
    // Empty with setup.start_only (no replicas ran).
    std::optional<ReplicaReport> replicas;
};

// What a caller sets for the ranks of mpi::design, beside the DesignSetup every design
// takes.
struct ReplicaSetup {
    ReplicaOptions options;
    // Called on rank 0 with every rank's threads and cores, before the start is made:
    // where a caller warns of a rank with more threads than cores (layout.overloaded_rank()).
    std::function<void(const RankLayout&)> layout;
};

// Designs a planned scene (plan_design, the same on every rank) on the ranks of `comm`,
// one replica per rank (see the top of this file); setup.initial is not read (the plan
// holds the start surface). Throws InputError, on every rank, for options that cannot
// be designed.
inline ReplicaDesign design(PlannedDesign plan, const ImageD& target, const DesignSetup& setup, MPI_Comm comm,
                            const ReplicaSetup& replica_setup = {}) {
    int rank = 0;
    detail::check(MPI_Comm_rank(comm, &rank), "MPI_Comm_rank");
    ReplicaDesign out;
    if (setup.start_only) {
        if (rank == 0) out.design = freeform::design(std::move(plan), target, setup);
        return out;
    }
    Replicas replicas(comm, plan.options.seed, replica_setup.options);
    ReplicaReport report;
    report.ranks = replicas.size();
    report.options = replicas.options();
    report.layout = rank_layout(comm, thread_count(exec::omp_t{plan.options.threads}));
    if (rank == 0 && replica_setup.layout) replica_setup.layout(report.layout);
    if (setup.callbacks.phase) setup.callbacks.phase(finding_the_start(plan.scene));
    DesignResult result = pipeline_detail::anneal(plan, target, setup, replicas);
    report.iterations_all = replicas.sum_on_root(result.iterations);
    // Ranks that share one surface all worked on the design: its moves are theirs.
    if (replicas.shares_surface() && rank == 0) result.iterations = report.iterations_all;
    report.winner = replicas.gather_best(result, &report.objectives);
    report.judged_held_out = result.held_out.total >= 0;
    report.merges = replicas.merges();
    report.exchange_points = replicas.exchange_points();
    report.pairs = replicas.pairs();
    report.final_rungs = replicas.rungs();
    out.stopped_early = result.stopped_early;
    out.replicas = std::move(report);
    // Rank 0 alone finishes the winner's design.
    if (rank == 0) out.design = pipeline_detail::finish(plan, std::move(result), target, setup);
    return out;
}

// Designs the job on the ranks of `comm`: plans it (plan_design) and designs the plan.
// Throws InputError, on every rank, for a scene or options that cannot be designed.
inline ReplicaDesign design(const DesignJob& job, const ImageD& target, const DesignSetup& setup, MPI_Comm comm,
                            const ReplicaSetup& replica_setup = {}) {
    return design(plan_design(job, setup.initial), target, setup, comm, replica_setup);
}

// metrics.json's "replicas" block: how the ranks shared the design (rank 0's report).
inline nlohmann::json replicas_json(const ReplicaReport& report) {
    using json = nlohmann::json;
    const ReplicaOptions& o = report.options;
    const int ranks = report.ranks;
    json r;
    r["ranks"] = ranks;
    r["mode"] = to_string(o.mode);
    const bool domains = o.mode == ReplicaMode::domains;
    if (domains) {
        r["exchange"] = "surfaces: every rank's changes since the last merge are added up";
        r["merges"] = report.merges;
        json rows = json::array();
        for (int k = 0; k < ranks; ++k) rows.push_back(json::array({double(k) / ranks, double(k + 1) / ranks}));
        r["rows_per_rank"] = rows;  // fractions of the mesh's rows each rank moves
        r["merge_coverage"] = o.merge_coverage;
    } else {
        r["ladder"] = "geometric";
        r["ladder_ratio"] = o.ladder_ratio;
        json scales = json::array();
        for (int k = 0; k < ranks; ++k) scales.push_back(std::pow(o.ladder_ratio, double(k)));
        r["rung_temperature_scales"] = scales;
        r["exchange"] = "temperatures";
        json pairs = json::array();
        for (const PairStats& p : report.pairs)
            pairs.push_back({{"rungs", json::array({p.cold_rung, p.cold_rung + 1})},
                             {"proposed", p.proposed},
                             {"accepted", p.accepted},
                             {"acceptance", p.proposed > 0 ? double(p.accepted) / double(p.proposed) : 0.0}});
        r["pairs"] = pairs;
        r["winner_final_rung"] = report.final_rungs[std::size_t(report.winner)];
        r["final_rungs"] = report.final_rungs;
    }
    if (o.exchange_every > 0)
        r["exchange_every"] = o.exchange_every;
    else
        r["exchange_every"] = domains ? "automatic: merges every merge_coverage x (mesh vertices / ranks) / kernel "
                                        "support^2 iterations, at least 500; the ranks meet every 500 to stop "
                                        "together"
                                      : "automatic: 500";
    r["exchange_points"] = report.exchange_points;
    r["winner_rank"] = report.winner;
    r["objectives"] = report.objectives;  // what picked the winner: held-out when checked
    r["objectives_judged_on"] = report.judged_held_out ? "held-out rays" : "fitted rays";
    r["iterations_all_ranks"] = report.iterations_all;
    r["threads_per_rank"] = report.layout.threads;
    r["cores_per_rank"] = report.layout.cores;  // cores each rank was bound to (0: unknown)
    r["seeds"] = "rank 0: the seed's own streams; rank r: hash(stage seed, r)";
    return r;
}

}  // namespace freeform::mpi
