// Ranks that share one design (freeform/mpi/replica_exchange.hpp, ReplicaMode::domains),
// run under `mpirun -np 2` (or more) by the ctest test mpi_domains:
//   1. the ranks' strips of rows are contiguous, disjoint and cover the mesh;
//   2. a merge gives every rank base + the sum of every rank's change since base, the
//      same floats on every rank (changes that overlap add up);
//   3. a whole design: every rank ends holding the same surface bit for bit, each stage
//      merged at least once, the design's error below its start's, and a second run
//      with the same seed ends on the same surface.
//   4. the same through mpi::design (freeform/mpi/design.hpp), the one entry point: rank 0
//      alone holds the finished design, on the surface the annealing core with the
//      coordinator ends on; every rank reports the run (merges, the winner, rank 0 the
//      moves of all ranks and the layout); the start alone runs on rank 0 alone.
#include <mpi.h>

#include <cmath>
#include <cstdio>
#include <cstring>
#include <string>
#include <vector>

#include <freeform/mpi/design.hpp>
#include <freeform/mpi/replica_exchange.hpp>

#include "../support.hpp"
#include "check.hpp"

using namespace freeform;
using testing::mpi_check::expect;
using testing::mpi_check::rank;

namespace {

int size = 1;

// Every rank's copy of `v`, in rank order.
std::vector<float> gather_all(const std::vector<float>& v) {
    std::vector<float> all(v.size() * std::size_t(size));
    MPI_Allgather(v.data(), int(v.size()), MPI_FLOAT, all.data(), int(v.size()), MPI_FLOAT, MPI_COMM_WORLD);
    return all;
}

bool same_on_every_rank(const std::vector<float>& v) {
    const std::vector<float> all = gather_all(v);
    for (int r = 1; r < size; ++r)
        if (std::memcmp(all.data(), all.data() + std::size_t(r) * v.size(), v.size() * sizeof(float)) != 0) return false;
    return true;
}

void check_rows(const mpi::Replicas& replicas, int ny) {
    const auto [j0, j1] = replicas.centre_rows(ny);
    const int mine[2] = {j0, j1};
    std::vector<int> all(std::size_t(2 * size));
    MPI_Allgather(mine, 2, MPI_INT, all.data(), 2, MPI_INT, MPI_COMM_WORLD);
    expect(all.front() == 0 && all.back() == ny, "strips start at row 0 and end at row ny = " + std::to_string(ny));
    for (int r = 0; r < size; ++r) {
        expect(all[std::size_t(2 * r)] < all[std::size_t(2 * r + 1)] || ny < size, "a strip is not empty");
        if (r > 0) expect(all[std::size_t(2 * r)] == all[std::size_t(2 * r - 1)], "strips are contiguous and disjoint");
    }
}

void check_merge(mpi::Replicas& replicas) {
    const std::size_t n = 40;
    std::vector<float> base(n);
    for (std::size_t k = 0; k < n; ++k) base[k] = 0.01f * float(k) - 0.1f;
    std::vector<float> mine = base;
    // Rank r changes vertex r (its own) and vertex n-1 (everyone's), by amounts that are
    // not exact in binary.
    mine[std::size_t(rank)] += 0.003f * float(rank + 1);
    mine[n - 1] += 0.0007f * float(rank + 1);
    const std::vector<float> sent = mine;
    std::vector<float> all = gather_all(sent);
    replicas.merge(mine, base);
    for (std::size_t k = 0; k < n; ++k) {
        double want = base[k];
        for (int r = 0; r < size; ++r) want += double(all[std::size_t(r) * n + k]) - double(base[k]);
        expect(mine[k] == float(want), "merged vertex " + std::to_string(k) + " is base + every rank's change");
    }
    expect(std::abs(double(mine[n - 1]) - (double(base[n - 1]) + 0.0007 * size * (size + 1) / 2)) < 1e-6,
           "changes of several ranks to one vertex add up");
    expect(same_on_every_rank(mine), "every rank holds the same merged heights");
    expect(replicas.merges() == 1, "merges counted");
}

mpi::ReplicaOptions domains_every(std::int64_t iterations) {
    mpi::ReplicaOptions ro;
    ro.mode = mpi::ReplicaMode::domains;
    ro.exchange_every = iterations;
    return ro;
}

// A small design: 31² mesh on a 40² receiver, flat start, 1,500 iterations a rank.
DesignJob small_job(std::uint64_t seed) {
    DesignJob job{testing::basic_scene(40, 8), {}};
    Scene& s = job.scene;
    s.surface.nx = s.surface.ny = 31;
    s.receiver.deposit = Deposit::bilinear;
    s.target = TargetSpec{};
    s.surface.initial_shape = InitialShape::flat;
    DesignOptions& o = job.options;
    o.seed = seed;
    o.time_budget = 0;
    o.max_iterations = 1500;
    o.threads = 1;
    return job;
}

std::vector<float> design_once(std::uint64_t seed, std::vector<StageReport>& stages, double& error_start,
                               double& error_end) {
    mpi::Replicas replicas(MPI_COMM_WORLD, seed, domains_every(150));
    const DesignJob job = small_job(seed);
    const Scene& s = job.scene;
    const ImageD target = testing::two_blocks(40, 40);
    const DesignOptions& o = job.options;
    const DesignResult r =
        design(s, testing::surface_for(s, 31), target, o, [](const DesignProgress&) { return false; }, default_penalties(o.penalties),
               replicas);
    stages = r.stages;
    error_start = r.stages.front().error_start;
    error_end = r.value.error;
    return r.surface.heights();
}

void check_mpi_design() {
    const DesignJob job = small_job(13);
    const ImageD target = testing::two_blocks(40, 40);
    DesignSetup setup;
    setup.export_checks = false;
    mpi::ReplicaSetup rs;
    rs.options = domains_every(150);
    int layouts = 0;
    rs.layout = [&](const mpi::RankLayout& l) {
        ++layouts;
        expect(int(l.threads.size()) == size && l.threads.front() == 1, "the layout lists every rank's threads");
    };
    const mpi::ReplicaDesign r = mpi::design(job, target, setup, MPI_COMM_WORLD, rs);
    expect(r.design.has_value() == (rank == 0), "rank 0 alone holds the design");
    expect(layouts == (rank == 0 ? 1 : 0), "the layout is handed to rank 0 alone");
    expect(!r.stopped_early, "the design ran to its budget");
    expect(r.replicas && r.replicas->ranks == size && r.replicas->winner == 0 && r.replicas->merges >= 1,
           "every rank reports the run: its ranks, merges, and rank 0 winning (one shared surface)");

    // The annealing core with the coordinator, on the scene as design() plans it.
    PlannedDesign plan = plan_design(job);
    mpi::Replicas replicas(MPI_COMM_WORLD, job.options.seed, domains_every(150));
    const DesignResult core = design(plan.scene, std::move(plan.initial), target, plan.options,
                                     [](const DesignProgress&) { return false; },
                                     default_penalties(plan.options.penalties), replicas);
    if (rank == 0 && r.design) {
        const CompletedDesign& d = *r.design;
        expect(d.result.surface.heights() == core.surface.heights(),
               "mpi::design ends on the surface of the core's design over the same ranks");
        expect(r.replicas->iterations_all == d.result.iterations && d.result.iterations == size * core.iterations,
               "domains: the design's moves are every rank's");
        expect(d.fitted.error > 0 && !d.error_physical(), "finished on rank 0, the export left out");
        expect(d.delivered && !d.delivered->start && d.delivered->annealed_error < d.delivered->start_error,
               "rank 0's finish holds the start to compare with, and the annealed surface traces better than flat");
    }

    setup.start_only = true;
    const mpi::ReplicaDesign start = mpi::design(job, target, setup, MPI_COMM_WORLD, rs);
    expect(start.design.has_value() == (rank == 0) && !start.replicas && !start.stopped_early,
           "the start alone: rank 0 alone, no replicas");
    if (start.design) expect(start.design->result.iterations == 0, "the start alone is not annealed");
}

}  // namespace

int main(int argc, char** argv) {
    MPI_Init(&argc, &argv);
    MPI_Comm_rank(MPI_COMM_WORLD, &rank);
    MPI_Comm_size(MPI_COMM_WORLD, &size);
    try {
        mpi::ReplicaOptions ro;
        ro.mode = mpi::ReplicaMode::domains;
        mpi::Replicas replicas(MPI_COMM_WORLD, 7, ro);
        expect(replicas.shares_surface() == (size > 1), "domains share one surface when there are several ranks");
        for (int ny : {7, 31, 101}) check_rows(replicas, ny);
        check_merge(replicas);

        std::vector<StageReport> stages;
        double start = 0, end = 0;
        const std::vector<float> a = design_once(11, stages, start, end);
        expect(same_on_every_rank(a), "every rank ends the design on the same surface, bit for bit");
        for (const StageReport& st : stages)
            expect(st.merges >= 1, "level " + std::to_string(st.level) + " stage merged " + std::to_string(st.merges) +
                                       " times");
        expect(std::isfinite(end) && end < start, "the design lowers the error: " + std::to_string(start) + " -> " +
                                                       std::to_string(end));
        std::vector<StageReport> again_stages;
        double s2 = 0, e2 = 0;
        const std::vector<float> b = design_once(11, again_stages, s2, e2);
        expect(a == b, "the same seed and rank count give the same design");
        check_mpi_design();
        if (rank == 0 && testing::mpi_check::failures == 0)
            std::printf("ok   domains over %d ranks: %zu stages, error %.4f -> %.4f\n", size, stages.size(), start, end);
    } catch (const std::exception& e) {
        expect(false, std::string("unexpected exception: ") + e.what());
    }
    return testing::mpi_check::finish("ok   domains over " + std::to_string(size) +
                  " ranks: strips, merges, a whole design and mpi::design agree on every rank");
}
