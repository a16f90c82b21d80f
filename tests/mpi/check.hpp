#pragma once
// What the MPI test programs share: checks that report the rank that failed, and one
// verdict for all ranks at the end.
#include <mpi.h>

#include <cstdio>
#include <string>

namespace freeform::testing::mpi_check {

inline int rank = 0;
inline int failures = 0;

inline void expect(bool ok, const std::string& what) {
    if (ok) return;
    std::fprintf(stderr, "rank %d: FAILED: %s\n", rank, what.c_str());
    ++failures;
}

// Sums the failures of every rank, prints `ok_line` (or the count) on rank 0, ends MPI;
// returns the exit code.
inline int finish(const std::string& ok_line) {
    int total = 0;
    MPI_Allreduce(&failures, &total, 1, MPI_INT, MPI_SUM, MPI_COMM_WORLD);
    if (rank == 0) {
        if (total == 0)
            std::printf("%s\n", ok_line.c_str());
        else
            std::printf("%d check(s) failed\n", total);
    }
    MPI_Finalize();
    return total == 0 ? 0 : 1;
}

}  // namespace freeform::testing::mpi_check
