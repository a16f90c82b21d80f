// Uses an installed freeform::mpi under `mpiexec -np 2`: the replica coordinator over
// MPI_COMM_WORLD agrees on the values every replica must share (iteration budget, stop
// decision), and a start made on rank 0 reaches the other ranks bit for bit.
#include <mpi.h>

#include <cstdint>
#include <cstdio>
#include <cstring>
#include <vector>

#include <freeform/mpi/replica_exchange.hpp>

int main(int argc, char** argv) {
    using namespace freeform;
    MPI_Init(&argc, &argv);
    int rank = 0, size = 1, bad = 0;
    MPI_Comm_rank(MPI_COMM_WORLD, &rank);
    MPI_Comm_size(MPI_COMM_WORLD, &size);
    try {
        mpi::Replicas replicas(MPI_COMM_WORLD, 7);
        // The budget every replica uses is the mean of the ranks' (100, 200, ...).
        if (replicas.common_budget(100 * (rank + 1)) != 50 * (size + 1)) {
            std::fprintf(stderr, "FAIL: rank %d: common_budget\n", rank);
            ++bad;
        }
        if (!replicas.any(rank == size - 1)) {
            std::fprintf(stderr, "FAIL: rank %d: any() missed the last rank's true\n", rank);
            ++bad;
        }
        const auto make = [] {
            SharedStart s;
            s.surface = Heightmap(5, 4, {0.1, 0.08}, -0.01, 0.01);
            std::vector<float> h(20);
            for (std::size_t k = 0; k < h.size(); ++k) h[k] = 1e-4f * float(k) - 7e-4f;
            s.surface.set_heights(h);
            s.report.plan = "made on rank 0";
            s.skip = 1;
            return s;
        };
        int made = 0;
        const SharedStart got = replicas.share_start([&] {
            ++made;
            return make();
        });
        const SharedStart own = make();
        const std::vector<float>&a = got.surface.heights(), &b = own.surface.heights();
        if (made != (rank == 0 ? 1 : 0) || a.size() != b.size() ||
            std::memcmp(a.data(), b.data(), a.size() * sizeof(float)) != 0 || got.report.plan != own.report.plan ||
            got.skip != own.skip) {
            std::fprintf(stderr, "FAIL: rank %d: the start shared by rank 0 differs from its own\n", rank);
            ++bad;
        }
    } catch (const std::exception& e) {
        std::fprintf(stderr, "FAIL: rank %d: %s\n", rank, e.what());
        ++bad;
    }
    int total = 0;
    MPI_Allreduce(&bad, &total, 1, MPI_INT, MPI_SUM, MPI_COMM_WORLD);
    if (rank == 0 && total == 0) std::printf("consumer mpi OK (%d ranks)\n", size);
    MPI_Finalize();
    return total == 0 ? 0 : 1;
}
