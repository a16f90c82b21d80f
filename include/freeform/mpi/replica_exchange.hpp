#pragma once
// Replica-exchange annealing over MPI: one replica of the design per rank (CMake target
// freeform::mpi, built only where MPI is found), or one design shared by the ranks
// (domains, below). The annealer and the designer stay free of MPI; this file is the
// coordinator they are given (design/replicas.hpp).
//
// The method ("parallel tempering"). Rank r anneals its own copy of the design with its
// own random streams (rank 0 with exactly the streams of a plain design), at the
// designer's temperature schedule multiplied by the scale of its rung on a ladder:
//
//   scale(rung k) = ladder_ratio^k,   k = 0 (coldest, the plain schedule) ... ranks − 1.
//
// A geometric ladder: for a system whose energy fluctuations grow in proportion to the
// temperature (a roughly constant heat capacity, which is what an error summed over many
// independent receiver cells behaves like) neighbouring rungs then overlap equally, so
// every pair swaps at about the same rate, and the hottest rung is ratio^(n−1) times the
// schedule. The default ratio, 1.5, keeps the hottest of 4 rungs at 3.4 × the calibrated
// temperature, where the hot replica still shapes light instead of wandering.
//
// Every exchange_every iterations of a stage the ranks meet (MPI_Allgather of energy,
// temperature and "I would stop here"). Neighbouring rungs (k, k+1) propose to swap
// temperatures and accept with the Metropolis rule
//
//   p = min(1, exp((1/T_k − 1/T_{k+1}) · (E_k − E_{k+1}))),
//
// the uniform number drawn from a stream keyed by the seed and a counter that every rank
// advances alike, so all ranks take the same decisions without further messages. With 3
// or more rungs the pairs alternate between even and odd k (pairs are disjoint, each
// rank moves at most one rung per exchange); with 2 rungs the one pair is proposed every
// time.
//
// What is swapped: the temperatures, not the surfaces. A temperature is one number;
// a surface is the height field plus the incremental tracer's state built on it (per-cell
// ray lists, the histogram, the objective's sums): sending it means megabytes per swap
// and a full retrace on arrival. Swapping temperatures gives the same Markov chain over
// (surface, temperature) pairs for the price of the 4 doubles each rank sends anyway.
// A swap gives each rank exactly the other's current temperature, by multiplying its
// scale by T_other / T_own: re-heats happen per replica, so two replicas' schedules can
// be at different points, and the rule above must use (and hand over) the temperatures
// the replicas really run at. When the schedules are in step, which is the usual case,
// this is the swap of the two rungs' scales. Rungs are tracked as labels for the report
// and a new stage starts every rank at the scale of the rung it holds.
//
// The start: rank 0 alone computes the design's start (the transport solve and the
// schedule's judgement of it, design/start.hpp) and broadcasts it (share_start); the
// other ranks wait without spinning, so rank 0 has the cores they share. Every rank
// thus starts from the same surface bit for bit, and the start costs one solve per run,
// not one per rank.
//
// The result: each replica ends every stage holding its best state; at the end the
// replica with the lowest objective (ties: the lowest rank) wins and its result is sent
// to rank 0 (gather_best). With one rank all of this reduces to the plain design, bit
// for bit (the exchange points only split the annealer's windows, which does not change
// its trajectory).
//
// Domains (ReplicaMode::domains). Tempering pays only where annealing must escape local
// minima; ours, from a transport start and a calibrated, near-greedy schedule, rarely
// must, and n replicas then do n times the work for one design's worth of progress
// (docs/performance.md, "MPI: ranks against threads", its third tempering study; results:
// git show 23d0eb2:benchmarks/results/mpi_v3/summary.md). In this mode the ranks are not
// copies but parts of one design: rank r centres its moves on the mesh rows
// [r·ny/n, (r+1)·ny/n) (a kernel reaches support/2 rows beyond), with its own random
// streams, and every merge_every iterations every rank's change since the last merge is
// added to the merged surface:
//
//   merged = base + Σ_r (h_r − base),
//
// in double, in rank order, then rounded and clamped once (Heightmap::set_heights), so
// every rank computes the same floats. Moves are additive bumps, so the merge is the
// composition of every rank's accepted moves; each rank judged its moves against the
// others' surface as of the last merge, which is what keeps merges frequent: the
// automatic interval moves each vertex of a strip about merge_coverage times (30 by
// default) between merges, N = merge_coverage · (nx·ny/n) / support², at least 500
// iterations; a merge costs one full retrace per rank (the state is rebuilt from the
// merged heights), about as much as nx·ny/support² moves, so the overhead is about
// 1/merge_coverage of a move-bound stage or less. The ranks still meet every 500
// iterations between merges (4 doubles each), to stop together when the time is up: a
// time-budgeted run overran its budget by up to one merge interval (2.3 s of 20 on the
// letter E) when they met only to merge. After a merge each rank's annealer goes on
// from the merged state, which is also its new best (AnnealExchange::state_replaced);
// a stage ends with one more merge of the ranks' best states, so all ranks start the
// next stage, and end the design, on the same surface bit for bit, and the held-out
// checks judge merged states only. The ranks do n times the moves of one rank per
// second of wall time, without the per-move synchronisation threads need.
//
// Failure: a rank that dies makes the others wait in the next collective until the MPI
// runtime ends the job (Open MPI's mpirun kills every rank and exits non-zero, naming
// the rank); nothing here writes files, so a caller that writes only after gather_best
// leaves no partial output.
#include <mpi.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <exception>
#include <functional>
#include <limits>
#include <optional>
#include <stdexcept>
#include <string>
#include <string_view>
#include <thread>
#include <type_traits>
#include <utility>
#include <vector>

#include "../core/rng.hpp"
#include "../design/designer.hpp"
#include "../design/replicas.hpp"

namespace freeform::mpi {

// What the ranks are to each other: replicas of the whole design at a ladder of
// temperatures that swap temperatures (tempering), or workers on strips of one design
// that merge their surfaces (domains; see "Domains" at the top).
enum class ReplicaMode { tempering, domains };

inline constexpr std::array<EnumName<ReplicaMode>, 2> replica_mode_names{
    {{"tempering", ReplicaMode::tempering}, {"domains", ReplicaMode::domains}}};

inline std::string_view to_string(ReplicaMode m) { return enum_name(m, replica_mode_names); }


// The default is domains: at equal cores and wall time it beat one rank on every case
// measured, where tempering lost (docs/performance.md, "MPI: ranks against threads"; how
// to run it: docs/cli.md, "freeform_mpi: one design on several ranks"; every run: git
// show 1845597:benchmarks/results/mpi_domains/README.md).
struct ReplicaOptions {
    ReplicaMode mode = ReplicaMode::domains;
    double ladder_ratio = 1.5;          // tempering: scale of rung k = ladder_ratio^k; ≥ 1
    // Iterations between exchange points (domains: merges); 0 = automatic: 500 for
    // tempering; for domains, as many as move each vertex of a rank's strip about
    // merge_coverage times (see "Domains" above).
    std::int64_t exchange_every = 0;
    // 30: lower errors than 10 on 16 of 20 paired runs (camera and letter E, 10 seeds;
    // docs/performance.md, "MPI: ranks against threads", "The merge interval"; runs: git
    // show 1845597:benchmarks/results/mpi_domains/c10, .../c30); larger values were not tried.
    double merge_coverage = 30;
};

inline void validate(const ReplicaOptions& o) {
    if (!std::isfinite(o.ladder_ratio) || o.ladder_ratio < 1)
        throw InputError("replicas: ladder_ratio must be a finite number ≥ 1, got " + std::to_string(o.ladder_ratio));
    if (o.exchange_every < 0)
        throw InputError("replicas: exchange_every must be ≥ 0 (0 = automatic), got " + std::to_string(o.exchange_every));
    if (!std::isfinite(o.merge_coverage) || o.merge_coverage <= 0)
        throw InputError("replicas: merge_coverage must be a finite number > 0, got " + std::to_string(o.merge_coverage));
}

// Swap statistics of the rung pair (k, k+1).
struct PairStats {
    int cold_rung = 0;
    std::int64_t proposed = 0;
    std::int64_t accepted = 0;
};

namespace detail {

inline void check(int code, const char* what) {
    if (code != MPI_SUCCESS) throw std::runtime_error(std::string("MPI: ") + what + " failed");
}

inline constexpr std::uint64_t exchange_stream = 0x65786368616e6765ULL;  // "exchange"
inline constexpr std::uint64_t replica_stream = 0x7265706c696361ULL;     // "replica"

// A byte buffer for sending a result from one rank to another (same program, same
// machine type: values are copied as they are in memory).
class Packer {
public:
    template <class T>
    void put(const T& v) {
        static_assert(std::is_trivially_copyable_v<T>);
        const auto* p = reinterpret_cast<const char*>(&v);
        bytes.insert(bytes.end(), p, p + sizeof(T));
    }
    template <class T>
    void put_vector(const std::vector<T>& v) {
        static_assert(std::is_trivially_copyable_v<T>);
        put<std::uint64_t>(v.size());
        const auto* p = reinterpret_cast<const char*>(v.data());
        bytes.insert(bytes.end(), p, p + v.size() * sizeof(T));
    }
    void put_string(const std::string& s) {
        put<std::uint64_t>(s.size());
        bytes.insert(bytes.end(), s.begin(), s.end());
    }
    std::vector<char> bytes;
};

class Unpacker {
public:
    explicit Unpacker(const std::vector<char>& b) : bytes_(b) {}
    template <class T>
    T get() {
        static_assert(std::is_trivially_copyable_v<T>);
        need(sizeof(T));
        T v;
        std::memcpy(&v, bytes_.data() + at_, sizeof(T));
        at_ += sizeof(T);
        return v;
    }
    template <class T>
    std::vector<T> get_vector() {
        const auto n = std::size_t(get<std::uint64_t>());
        need(n * sizeof(T));
        std::vector<T> v(n);
        if (n > 0) std::memcpy(v.data(), bytes_.data() + at_, n * sizeof(T));
        at_ += n * sizeof(T);
        return v;
    }
    std::string get_string() {
        const auto n = std::size_t(get<std::uint64_t>());
        need(n);
        std::string s(bytes_.data() + at_, n);
        at_ += n;
        return s;
    }

private:
    void need(std::size_t n) const {
        if (at_ + n > bytes_.size()) throw std::runtime_error("replicas: truncated result message");
    }
    const std::vector<char>& bytes_;
    std::size_t at_ = 0;
};

// What rank 0 needs of another rank's result. The start report and the target are the
// same on every rank (rank 0 made the start; the rays use the common seed) and are not
// sent.
inline std::vector<char> pack_result(const DesignResult& r) {
    Packer p;
    p.put(r.surface.nx());
    p.put(r.surface.ny());
    p.put_vector(r.surface.heights());
    p.put(r.irradiance.width);
    p.put(r.irradiance.height);
    p.put_vector(r.irradiance.cells);
    p.put(r.value);
    p.put(r.iterations);
    p.put(r.accepted);
    p.put(r.seconds);
    p.put(r.stopped_early);
    p.put<std::uint64_t>(r.stages.size());
    for (const StageReport& s : r.stages) {
        p.put(s.level), p.put(s.mesh_x), p.put(s.mesh_y), p.put(s.resolution_x), p.put(s.resolution_y);
        p.put(s.kernel_support), p.put(s.iterations), p.put(s.accepted), p.put(s.proposals_evaluated);
        p.put(s.seconds), p.put(s.initial_temperature), p.put(s.error_start), p.put(s.error_end);
        p.put(s.energy_end), p.put(s.objective_end), p.put(s.rays);
        p.put(s.held_out_start), p.put(s.held_out_end), p.put(s.held_out_checks), p.put(s.held_out_kept);
        p.put(s.merges);
        p.put_vector(s.bandit_weights);
        p.put(s.stop_reason);
    }
    p.put_vector(r.convergence);
    p.put_vector(r.kernel_bank);
    p.put_vector(r.bandit_weights);
    p.put_vector(r.preprocess_rates);
    p.put(r.rays);
    p.put(r.held_out);
    p.put(r.held_out_seed);
    return std::move(p.bytes);
}

inline void unpack_result(const std::vector<char>& bytes, DesignResult& r) {
    Unpacker u(bytes);
    const int nx = u.get<int>(), ny = u.get<int>();
    std::vector<float> heights = u.get_vector<float>();
    if (nx != r.surface.nx() || ny != r.surface.ny())
        throw std::runtime_error("replicas: the winning replica's mesh differs from rank 0's");
    r.surface.set_heights(heights);
    r.irradiance.width = u.get<int>();
    r.irradiance.height = u.get<int>();
    r.irradiance.cells = u.get_vector<Fixed>();
    r.value = u.get<ObjectiveValue>();
    r.iterations = u.get<std::int64_t>();
    r.accepted = u.get<std::int64_t>();
    r.seconds = u.get<double>();
    r.stopped_early = u.get<bool>();
    r.stages.resize(std::size_t(u.get<std::uint64_t>()));
    for (StageReport& s : r.stages) {
        s.level = u.get<int>(), s.mesh_x = u.get<int>(), s.mesh_y = u.get<int>();
        s.resolution_x = u.get<int>(), s.resolution_y = u.get<int>(), s.kernel_support = u.get<int>();
        s.iterations = u.get<std::int64_t>(), s.accepted = u.get<std::int64_t>();
        s.proposals_evaluated = u.get<std::int64_t>();
        s.seconds = u.get<double>(), s.initial_temperature = u.get<double>(), s.error_start = u.get<double>();
        s.error_end = u.get<double>(), s.energy_end = u.get<double>(), s.objective_end = u.get<double>();
        s.rays = u.get<std::int64_t>();
        s.held_out_start = u.get<double>(), s.held_out_end = u.get<double>();
        s.held_out_checks = u.get<std::int64_t>(), s.held_out_kept = u.get<std::int64_t>();
        s.merges = u.get<std::int64_t>();
        s.bandit_weights = u.get_vector<double>();
        s.stop_reason = u.get<StopReason>();
    }
    r.convergence = u.get_vector<ConvergencePoint>();
    r.kernel_bank = u.get_vector<KernelShape>();
    r.bandit_weights = u.get_vector<double>();
    r.preprocess_rates = u.get_vector<double>();
    r.rays = u.get<std::int64_t>();
    r.held_out = u.get<ObjectiveValue>();
    r.held_out_seed = u.get<std::uint64_t>();
}

// The start every replica of a design uses (design/start.hpp), sent by the rank that
// computed it. The surface goes as its placement and heights; the receiver rebuilds it
// (the normals follow from the heights, as everywhere: Heightmap::set_heights).
inline void pack_transport_report(Packer& p, const TransportReport& t) {
    p.put(t.used);
    p.put_string(t.fallback_reason);
    p.put(t.grid_x), p.put(t.grid_y), p.put(t.cell_size), p.put(t.ot_iterations), p.put(t.ot_residual);
    p.put(t.ot_seconds), p.put(t.fit_seconds), p.put(t.fit_iterations), p.put(t.height_range);
    p.put(t.height_excess), p.put(t.unmapped_fraction);
    p.put(t.strip_margin), p.put(t.wall_fraction), p.put(t.strip_light);
    p.put(t.cells_per_pixel), p.put(t.other_cells_per_pixel), p.put(t.other_error);
}

inline void unpack_transport_report(Unpacker& u, TransportReport& t) {
    t.used = u.get<bool>();
    t.fallback_reason = u.get_string();
    t.grid_x = u.get<int>(), t.grid_y = u.get<int>(), t.cell_size = u.get<double>();
    t.ot_iterations = u.get<int>(), t.ot_residual = u.get<double>();
    t.ot_seconds = u.get<double>(), t.fit_seconds = u.get<double>(), t.fit_iterations = u.get<int>();
    t.height_range = u.get<double>(), t.height_excess = u.get<double>(), t.unmapped_fraction = u.get<double>();
    t.strip_margin = u.get<double>(), t.wall_fraction = u.get<double>(), t.strip_light = u.get<double>();
    t.cells_per_pixel = u.get<double>(), t.other_cells_per_pixel = u.get<double>(), t.other_error = u.get<double>();
}

inline void pack_start(Packer& p, const SharedStart& s) {
    const Heightmap& h = s.surface;
    p.put(h.nx()), p.put(h.ny()), p.put(h.size()), p.put(h.h_min()), p.put(h.h_max()), p.put(h.frame());
    p.put(h.aperture());
    p.put_vector(h.heights());
    const StartReport& r = s.report;
    p.put(r.requested), p.put(r.used), p.put_string(r.fallback_reason);
    pack_transport_report(p, r.transport);
    p.put(r.error), p.put(r.energy), p.put(r.flat_error), p.put(r.seconds);
    p.put(r.unreweighted_error), p.put(r.reweighted_error);
    p.put(r.plane_weighted_error), p.put(r.surface_weighted_error), p.put(r.lit_power_change);
    p.put(r.landing_offset), p.put(r.target_offset);
    p.put(r.levels_planned), p.put(r.levels_used);
    p.put_string(r.plan);
    p.put(s.transport), p.put(s.skip);
}

inline SharedStart unpack_start(Unpacker& u) {
    SharedStart s;
    const int nx = u.get<int>(), ny = u.get<int>();
    const Vec2d size = u.get<Vec2d>();
    const float h_min = u.get<float>(), h_max = u.get<float>();
    const Frame frame = u.get<Frame>();
    const Aperture aperture = u.get<Aperture>();
    s.surface = Heightmap(nx, ny, size, h_min, h_max, frame, aperture);
    s.surface.set_heights(u.get_vector<float>());
    StartReport& r = s.report;
    r.requested = u.get<StartKind>(), r.used = u.get<StartKind>(), r.fallback_reason = u.get_string();
    unpack_transport_report(u, r.transport);
    r.error = u.get<double>(), r.energy = u.get<double>(), r.flat_error = u.get<double>();
    r.seconds = u.get<double>();
    r.unreweighted_error = u.get<double>(), r.reweighted_error = u.get<double>();
    r.plane_weighted_error = u.get<double>(), r.surface_weighted_error = u.get<double>();
    r.lit_power_change = u.get<double>();
    r.landing_offset = u.get<double>(), r.target_offset = u.get<bool>();
    r.levels_planned = u.get<int>(), r.levels_used = u.get<int>();
    r.plan = u.get_string();
    s.transport = u.get<bool>();
    s.skip = u.get<int>();
    return s;
}

// Completes `request` without spinning on a core: a rank that waits here (for rank 0's
// start) leaves the cores it shares to the ranks that work. Blocking MPI calls poll,
// which on a machine with more threads than cores slows the one rank that computes.
inline void wait_idle(MPI_Request& request) {
    for (int done = 0;;) {
        check(MPI_Test(&request, &done, MPI_STATUS_IGNORE), "MPI_Test");
        if (done) return;
        std::this_thread::sleep_for(std::chrono::milliseconds(1));
    }
}

// What rank 0 broadcasts with the start: the start, or the error that made it fail.
enum class StartStatus : std::uint8_t { ok = 0, input_error = 1, other_error = 2 };

}  // namespace detail

// The coordinator of design() (design/replicas.hpp) for one replica per rank of `comm`.
// Every rank must make the same calls in the same order (design() does).
class Replicas {
public:
    Replicas(MPI_Comm comm, std::uint64_t seed, ReplicaOptions options = {})
        : comm_(comm), options_(options), exchange_key_(hash_combine(seed, detail::exchange_stream)) {
        validate(options_);
        detail::check(MPI_Comm_rank(comm_, &rank_), "MPI_Comm_rank");
        detail::check(MPI_Comm_size(comm_, &size_), "MPI_Comm_size");
        rung_.resize(std::size_t(size_));
        for (int r = 0; r < size_; ++r) rung_[std::size_t(r)] = r;
        pairs_.resize(std::size_t(std::max(0, size_ - 1)));
        for (std::size_t k = 0; k < pairs_.size(); ++k) pairs_[k].cold_rung = int(k);
    }

    int rank() const { return rank_; }
    int size() const { return size_; }
    const ReplicaOptions& options() const { return options_; }
    // Rung held by each rank now, and the swap statistics of each neighbouring pair.
    const std::vector<int>& rungs() const { return rung_; }
    const std::vector<PairStats>& pairs() const { return pairs_; }
    std::int64_t exchange_points() const { return points_; }
    double rung_scale(int rung) const { return std::pow(options_.ladder_ratio, double(rung)); }

    // --- the coordinator interface (design/replicas.hpp)
    bool active() const { return true; }
    // Rank 0 computes the start; the others wait idle (wait_idle) and receive it. An
    // exception on rank 0 is sent too and raised on every rank (an InputError as an
    // InputError: every rank then reports the same input error, as when each read it).
    SharedStart share_start(const std::function<SharedStart()>& make) const {
        if (size_ == 1) return make();
        detail::Packer p;
        SharedStart start;
        std::exception_ptr failure;
        if (rank_ == 0) {
            try {
                start = make();
                p.put(detail::StartStatus::ok);
                detail::pack_start(p, start);
            } catch (const InputError& e) {
                failure = std::current_exception();
                p.put(detail::StartStatus::input_error), p.put_string(e.what());
            } catch (const std::exception& e) {
                failure = std::current_exception();
                p.put(detail::StartStatus::other_error), p.put_string(e.what());
            }
        }
        std::uint64_t n = p.bytes.size();
        MPI_Request request;
        detail::check(MPI_Ibcast(&n, 1, MPI_UINT64_T, 0, comm_, &request), "MPI_Ibcast");
        detail::wait_idle(request);
        p.bytes.resize(std::size_t(n));
        detail::check(MPI_Bcast(p.bytes.data(), int(n), MPI_BYTE, 0, comm_), "MPI_Bcast");
        if (rank_ == 0) {
            if (failure) std::rethrow_exception(failure);
            return start;
        }
        detail::Unpacker u(p.bytes);
        const auto status = u.get<detail::StartStatus>();
        if (status == detail::StartStatus::ok) return detail::unpack_start(u);
        const std::string what = u.get_string();
        if (status == detail::StartStatus::input_error) throw InputError(what);
        throw std::runtime_error("rank 0 could not make the start: " + what);
    }
    std::uint64_t anneal_seed(std::uint64_t stage_seed) const {
        return rank_ == 0 ? stage_seed : hash_combine(stage_seed, detail::replica_stream + std::uint64_t(rank_));
    }
    double stage_temperature_scale() const {
        return shares_surface() ? 1.0 : rung_scale(rung_[std::size_t(rank_)]);
    }
    // Exchange points: every 500 iterations unless set; domains meet at least that often
    // (to decide together when the time is up), and merge every merge_every().
    std::int64_t exchange_every(int nx, int ny, int support) const {
        if (options_.exchange_every > 0) return options_.exchange_every;
        if (!shares_surface()) return stop_check_every;
        return std::min(stop_check_every, merge_every(nx, ny, support));
    }
    std::int64_t merge_every(int nx, int ny, int support) const {
        if (!shares_surface()) return 0;
        if (options_.exchange_every > 0) return options_.exchange_every;
        // A move changes about support² vertices; a rank's strip has nx·ny/ranks.
        const double strip = double(nx) * double(ny) / double(size_);
        const double footprint = double(std::max(1, support)) * double(std::max(1, support));
        return std::max<std::int64_t>(stop_check_every, std::llround(options_.merge_coverage * strip / footprint));
    }
    static constexpr std::int64_t stop_check_every = 500;
    double common_temperature(double t) const {
        detail::check(MPI_Bcast(&t, 1, MPI_DOUBLE, 0, comm_), "MPI_Bcast");
        return t;
    }
    // The mean of the ranks' budgets. In a time-budgeted design each rank fits its budget
    // to the speed it measured in a short calibration, which is noisy where ranks share
    // cores (one rank descheduled during its calibration measures a fraction of the real
    // speed): the minimum would let that rank starve every replica. The stage's time
    // limit is enforced at the exchange points anyway.
    std::int64_t common_budget(std::int64_t b) const {
        std::int64_t sum = 0;
        detail::check(MPI_Allreduce(&b, &sum, 1, MPI_INT64_T, MPI_SUM, comm_), "MPI_Allreduce");
        return std::max<std::int64_t>(1, sum / size_);
    }
    bool any(bool b) const {
        int in = b ? 1 : 0, out = 0;
        detail::check(MPI_Allreduce(&in, &out, 1, MPI_INT, MPI_LOR, comm_), "MPI_Allreduce");
        return out != 0;
    }

    bool exchange(ReplicaExchange& x) {
        const double mine[4] = {x.energy, x.temperature, x.temperature_scale, x.local_stop ? 1.0 : 0.0};
        all_.resize(std::size_t(4 * size_));
        detail::check(MPI_Allgather(mine, 4, MPI_DOUBLE, all_.data(), 4, MPI_DOUBLE, comm_), "MPI_Allgather");
        bool stop = false;
        for (int r = 0; r < size_; ++r) stop = stop || all_[std::size_t(4 * r + 3)] != 0;
        const std::int64_t point = points_++;
        if (stop || size_ < 2 || options_.mode == ReplicaMode::domains) return stop;

        std::vector<int> at_rung(static_cast<std::size_t>(size_));
        for (int r = 0; r < size_; ++r) at_rung[std::size_t(rung_[std::size_t(r)])] = r;
        const int first = size_ == 2 ? 0 : int(point % 2);
        for (int k = first; k + 1 < size_; k += 2) {
            const int i = at_rung[std::size_t(k)], j = at_rung[std::size_t(k + 1)];
            const double ei = all_[std::size_t(4 * i)], ti = all_[std::size_t(4 * i + 1)];
            const double ej = all_[std::size_t(4 * j)], tj = all_[std::size_t(4 * j + 1)];
            PairStats& ps = pairs_[std::size_t(k)];
            ++ps.proposed;
            // Every rank draws the same number for the same decision.
            CounterRng rng(exchange_key_, std::uint64_t(decisions_++));
            const double u = rng.uniform();
            if (!(ti > 0 && tj > 0)) continue;
            const double a = (1.0 / ti - 1.0 / tj) * (ei - ej);
            if (!(a >= 0 || u < std::exp(a))) continue;
            ++ps.accepted;
            std::swap(rung_[std::size_t(i)], rung_[std::size_t(j)]);
            // Each takes the other's temperature exactly (see the notes at the top).
            if (rank_ == i) x.temperature_scale = all_[std::size_t(4 * i + 2)] * (tj / ti);
            if (rank_ == j) x.temperature_scale = all_[std::size_t(4 * j + 2)] * (ti / tj);
        }
        return false;
    }

    // Domains: rank r moves rows [r ny / n, (r + 1) ny / n); merges add up every rank's
    // change since the last merge (in rank order, in double, so every rank computes the
    // same floats).
    bool shares_surface() const { return options_.mode == ReplicaMode::domains && size_ > 1; }
    std::pair<int, int> centre_rows(int ny) const {
        if (!shares_surface()) return {0, ny};
        const auto row = [&](int r) { return int(std::int64_t(r) * ny / size_); };
        return {row(rank_), row(rank_ + 1)};
    }
    void merge(std::vector<float>& heights, const std::vector<float>& base) {
        if (!shares_surface()) return;
        if (heights.size() != base.size()) throw std::runtime_error("replicas: merge of meshes of different sizes");
        const std::size_t n = heights.size();
        gathered_.resize(n * std::size_t(size_));
        if (n > std::size_t(std::numeric_limits<int>::max())) throw std::runtime_error("replicas: mesh too large to merge");
        detail::check(MPI_Allgather(heights.data(), int(n), MPI_FLOAT, gathered_.data(), int(n), MPI_FLOAT, comm_),
                      "MPI_Allgather");
        for (std::size_t k = 0; k < n; ++k) {
            const double b = base[k];
            double h = b;
            for (int r = 0; r < size_; ++r) h += double(gathered_[std::size_t(r) * n + k]) - b;
            heights[k] = float(h);
        }
        ++merges_;
    }
    std::int64_t merges() const { return merges_; }

    // --- the end of the run
    // Picks the replica with the lowest objective (ties: lowest rank) and moves its result
    // to rank 0; on rank 0 `result` is then the winner's. Returns the winning rank (on
    // every rank). `objectives` receives every rank's final objective, in rank order.
    // The objective is the held-out one when the design made held-out checks (every
    // replica has the same held-out rays): the fitted one favours the replica that fitted
    // its rays' noise best.
    static double judged(const DesignResult& r) { return r.held_out.total >= 0 ? r.held_out.total : r.value.total; }
    int gather_best(DesignResult& result, std::vector<double>* objectives = nullptr) const {
        struct {
            double value;
            int rank;
        } in{judged(result), rank_}, out{};
        if (!std::isfinite(in.value)) in.value = std::numeric_limits<double>::max();
        detail::check(MPI_Allreduce(&in, &out, 1, MPI_DOUBLE_INT, MPI_MINLOC, comm_), "MPI_Allreduce");
        if (objectives) {
            objectives->assign(std::size_t(size_), 0.0);
            double mine = judged(result);
            detail::check(MPI_Gather(&mine, 1, MPI_DOUBLE, objectives->data(), 1, MPI_DOUBLE, 0, comm_),
                          "MPI_Gather");
        }
        const int winner = out.rank;
        if (winner != 0) {
            constexpr int tag = 0x5245;
            if (rank_ == winner) {
                const std::vector<char> bytes = detail::pack_result(result);
                const std::uint64_t n = bytes.size();
                detail::check(MPI_Send(&n, 1, MPI_UINT64_T, 0, tag, comm_), "MPI_Send");
                detail::check(MPI_Send(bytes.data(), int(n), MPI_BYTE, 0, tag + 1, comm_), "MPI_Send");
            } else if (rank_ == 0) {
                std::uint64_t n = 0;
                detail::check(MPI_Recv(&n, 1, MPI_UINT64_T, winner, tag, comm_, MPI_STATUS_IGNORE), "MPI_Recv");
                std::vector<char> bytes(std::size_t(n), 0);
                detail::check(MPI_Recv(bytes.data(), int(n), MPI_BYTE, winner, tag + 1, comm_, MPI_STATUS_IGNORE),
                              "MPI_Recv");
                detail::unpack_result(bytes, result);
            }
        }
        return winner;
    }

    // Sums of an integer over all ranks, on rank 0 (e.g. iterations of all replicas).
    std::int64_t sum_on_root(std::int64_t v) const {
        std::int64_t out = 0;
        detail::check(MPI_Reduce(&v, &out, 1, MPI_INT64_T, MPI_SUM, 0, comm_), "MPI_Reduce");
        return out;
    }

private:
    MPI_Comm comm_;
    ReplicaOptions options_;
    std::uint64_t exchange_key_;
    int rank_ = 0, size_ = 1;
    std::vector<int> rung_;  // rung held by each rank
    std::vector<PairStats> pairs_;
    std::vector<double> all_;
    std::int64_t points_ = 0;     // exchange points met
    std::int64_t decisions_ = 0;  // swap decisions drawn
    std::vector<float> gathered_;  // domains: every rank's heights at a merge
    std::int64_t merges_ = 0;
};

static_assert(ReplicaCoordinator<Replicas>);

}  // namespace freeform::mpi
