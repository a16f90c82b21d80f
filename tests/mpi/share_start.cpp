// The start of a design shared over MPI (freeform/mpi/replica_exchange.hpp,
// Replicas::share_start), run under `mpirun -np 2` (or more) by the ctest test
// mpi_share_start:
//   1. rank 0 alone makes the start; every other rank receives it and holds exactly,
//      bit for bit, the start it would have made itself (the start is deterministic, so
//      each rank also makes its own copy to compare): the surface, its normals and
//      placement, the report (rank 0's timing included) and the schedule's decision;
//   2. an error while making the start on rank 0 reaches every rank as the same error
//      (an InputError as an InputError), and the ranks stay in step afterwards.
#include <mpi.h>

#include <cstdio>
#include <cstring>
#include <functional>
#include <stdexcept>
#include <string>
#include <vector>

#include <freeform/mpi/replica_exchange.hpp>

#include "../support.hpp"
#include "check.hpp"

using namespace freeform;
using testing::mpi_check::expect;
using testing::mpi_check::rank;

namespace {


template <class T>
bool same_bytes(const std::vector<T>& a, const std::vector<T>& b) {
    return a.size() == b.size() && std::memcmp(a.data(), b.data(), a.size() * sizeof(T)) == 0;
}

template <class T>
bool same_bytes(const T& a, const T& b) {
    return std::memcmp(&a, &b, sizeof(T)) == 0;
}

void check_same_start(const SharedStart& got, const SharedStart& own, double rank0_seconds) {
    const Heightmap &a = got.surface, &b = own.surface;
    expect(a.nx() == b.nx() && a.ny() == b.ny(), "mesh");
    expect(same_bytes(a.heights(), b.heights()), "heights, bit for bit");
    expect(same_bytes(a.normals(), b.normals()), "normals, bit for bit");
    expect(same_bytes(a.cell_mask(), b.cell_mask()), "aperture mask");
    expect(same_bytes(a.size(), b.size()) && a.h_min() == b.h_min() && a.h_max() == b.h_max(), "size and bounds");
    expect(same_bytes(a.frame(), b.frame()) && a.aperture() == b.aperture(), "frame and aperture");
    const StartReport &r = got.report, &o = own.report;
    expect(r.requested == o.requested && r.used == o.used && r.fallback_reason == o.fallback_reason, "start kind");
    expect(same_bytes(r.error, o.error) && same_bytes(r.energy, o.energy) && same_bytes(r.flat_error, o.flat_error),
           "start error, energy and flat error, bit for bit");
    expect(r.plan == o.plan && r.levels_planned == o.levels_planned && r.levels_used == o.levels_used, "plan");
    expect(r.seconds == rank0_seconds, "the report carries rank 0's timing");
    const TransportReport &t = r.transport, &u = o.transport;
    expect(t.used == u.used && t.fallback_reason == u.fallback_reason && t.grid_x == u.grid_x && t.grid_y == u.grid_y &&
               t.ot_iterations == u.ot_iterations && t.fit_iterations == u.fit_iterations,
           "transport report: counts");
    expect(same_bytes(t.cell_size, u.cell_size) && same_bytes(t.ot_residual, u.ot_residual) &&
               same_bytes(t.height_range, u.height_range) && same_bytes(t.height_excess, u.height_excess) &&
               same_bytes(t.unmapped_fraction, u.unmapped_fraction),
           "transport report: values, bit for bit");
    expect(got.transport == own.transport && got.skip == own.skip, "transport flag and levels skipped");
}

// The timing in rank 0's copy of the start, on every rank.
double rank0_seconds(const SharedStart& s) {
    double t = s.report.seconds;
    MPI_Bcast(&t, 1, MPI_DOUBLE, 0, MPI_COMM_WORLD);
    return t;
}

}  // namespace

int main(int argc, char** argv) {
    MPI_Init(&argc, &argv);
    int size = 1;
    MPI_Comm_rank(MPI_COMM_WORLD, &rank);
    MPI_Comm_size(MPI_COMM_WORLD, &size);
    try {
        mpi::Replicas replicas(MPI_COMM_WORLD, 5);

        Scene s;
        s.surface.frame = make_frame({0, 0, 0}, {0, 0, 1}, {0, 1, 0}, "surface");
        s.surface.aperture = Aperture::ellipse;
        s.surface.nx = s.surface.ny = 31;
        s.receiver.frame = make_frame({0, 0, 0.5}, {0, 0, -1}, {0, 1, 0}, "receiver");
        s.receiver.width = s.receiver.height = 60;
        s.receiver.deposit = Deposit::bilinear;
        s.light.rays_per_cell = 8;
        s.target = TargetSpec{};  // starts from the transport surface
        const ImageD target = testing::two_blocks(60, 60);  // a transport start well below flat
        DesignOptions o;
        o.seed = 5;
        o.start_level = 0;  // the first level (15²) runs: the start is fitted again on it
        const std::vector<LevelPlan> levels = plan_levels(s, o);
        const SurfaceSpec& sp = s.surface;
        const auto make = [&] {
            return prepare_start(s, Heightmap(31, 31, sp.size, sp.h_min, sp.h_max, sp.frame, sp.aperture), target, o,
                                 levels, 1);
        };

        int calls = 0;
        const SharedStart got = replicas.share_start([&] {
            ++calls;
            return make();
        });
        const SharedStart own = make();
        expect(calls == (rank == 0 ? 1 : 0), "make() runs on rank 0 alone");
        expect(own.transport && own.report.used == StartKind::transport, "the case starts from the transport surface");
        expect(levels.size() >= 2 && own.surface.nx() == levels.front().mesh_x && own.surface.nx() != 31,
               "the start is on the first level's mesh");
        check_same_start(got, own, rank0_seconds(got));

        try {
            (void)replicas.share_start([]() -> SharedStart { throw InputError("surface.initial: no light, say"); });
            expect(false, "an InputError on rank 0 must reach every rank");
        } catch (const InputError& e) {
            expect(std::string(e.what()) == "surface.initial: no light, say", std::string("InputError text: ") + e.what());
        }
        try {
            (void)replicas.share_start([]() -> SharedStart { throw std::runtime_error("solver blew up"); });
            expect(false, "a failure on rank 0 must reach every rank");
        } catch (const InputError&) {
            expect(false, "a failure that is not an input error arrived as an InputError");
        } catch (const std::exception& e) {
            expect(std::string(e.what()).find("solver blew up") != std::string::npos,
                   std::string("failure text: ") + e.what());
        }
        // Still in step: one more share after the two failures.
        const SharedStart again = replicas.share_start(make);
        check_same_start(again, own, rank0_seconds(again));
    } catch (const std::exception& e) {
        expect(false, std::string("unexpected exception: ") + e.what());
    }
    return testing::mpi_check::finish("ok   share_start over " + std::to_string(size) +
                  " ranks: made on rank 0 alone, received bit for bit; errors reach every rank");
}
