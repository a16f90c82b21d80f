#pragma once
// How the designer runs as one of several replicas (replica exchange, "parallel
// tempering"), without knowing how the replicas talk to each other.
//
// design() takes a coordinator; the default, SingleReplica, is the plain design and
// changes nothing. freeform/mpi/replica_exchange.hpp provides one over MPI (one replica per
// rank). Everything here is free of MPI and does no I/O.
//
// A coordinator provides:
//   bool active() const                 false: a single design (no exchange points; the
//                                       calls below then leave every value as it is)
//   SharedStart share_start(const std::function<SharedStart()>& make)
//                                       the design's start (start.hpp), the same on every
//                                       replica: calls make() on one replica and hands
//                                       the result to the others, so that the start (a
//                                       transport solve: seconds on a photograph) is
//                                       computed once per design, not once per replica;
//                                       an exception from make() is raised on every replica.
//                                       Its final_surface need only stay with the replica
//                                       that made it, which must be the one whose design
//                                       is finished (finish_design keeps the start when it
//                                       traces better)
//   std::uint64_t anneal_seed(std::uint64_t stage_seed)
//                                       the seed of a stage's annealing run on this replica
//                                       (stage_seed itself on replica 0; the rays, the start
//                                       and the calibration use the common seed, so every
//                                       replica minimises the same function)
//   double stage_temperature_scale()    the temperature scale a stage starts at (its rung
//                                       of the ladder)
//   std::int64_t exchange_every(int nx, int ny, int support) const
//                                       iterations between exchange points (> 0) in a stage
//                                       on an nx × ny mesh with kernels of `support` vertices
//   double common_temperature(double)   the initial temperature every replica uses
//   std::int64_t common_budget(std::int64_t)
//                                       the iteration budget every replica uses
//   bool any(bool)                      true on every replica when any passed true
//   bool exchange(ReplicaExchange&)     at an exchange point, on every replica at once:
//                                       may change temperature_scale; true = every
//                                       replica stops the stage here
//   bool shares_surface() const         true: the replicas are not copies but parts of one
//                                       design (domain decomposition): each moves only the
//                                       mesh rows centre_rows() gives it, and every
//                                       merge_every() iterations, at the end of every stage
//                                       and where the stage stops, they merge their
//                                       surfaces (merge) and all go on from the merged one
//   std::int64_t merge_every(int nx, int ny, int support) const
//                                       sharing: iterations between merges (a merge is made
//                                       at the first exchange point that far from the
//                                       last); otherwise 0
//   std::pair<int, int> centre_rows(int ny) const
//                                       the rows [j0, j1) of an ny-row mesh this replica
//                                       centres its moves on (all of them unless sharing)
//   void merge(std::vector<float>& heights, const std::vector<float>& base)
//                                       in: this replica's heights; out: the merged ones,
//                                       the same on every replica: base plus every
//                                       replica's change since base (the last merge)
// When active, the designer makes every decision that could end a stage at different
// iterations on different replicas a common one: the stage's time limit, a target error
// and a stop asked by the progress callback are checked at exchange points and passed
// to exchange() as local_stop, and the run stops where exchange() says. Budgets and
// initial temperatures, which the designer measures, go through common_*. Every replica
// thus reaches every exchange point of every stage, which is what a collective exchange
// needs.
#include <concepts>
#include <cstdint>
#include <functional>
#include <utility>
#include <vector>

#include "start.hpp"

namespace freeform {

struct ReplicaExchange {
    double energy = 0;             // this replica's current objective
    double best_energy = 0;        // its best in this stage
    double temperature = 0;        // the temperature its next iteration runs at
    double temperature_scale = 1;  // in: current scale; out: the scale from now on
    bool local_stop = false;       // this replica would stop here (time, target, user)
};

// The plain design: one replica, nothing exchanged.
struct SingleReplica {
    bool active() const { return false; }
    SharedStart share_start(const std::function<SharedStart()>& make) const { return make(); }
    std::uint64_t anneal_seed(std::uint64_t stage_seed) const { return stage_seed; }
    double stage_temperature_scale() const { return 1.0; }
    std::int64_t exchange_every(int, int, int) const { return 0; }
    double common_temperature(double t) const { return t; }
    std::int64_t common_budget(std::int64_t b) const { return b; }
    bool any(bool b) const { return b; }
    bool exchange(ReplicaExchange& x) const { return x.local_stop; }
    bool shares_surface() const { return false; }
    std::int64_t merge_every(int, int, int) const { return 0; }
    std::pair<int, int> centre_rows(int ny) const { return {0, ny}; }
    void merge(std::vector<float>&, const std::vector<float>&) const {}
};

template <class C>
concept ReplicaCoordinator = requires(C& c, const C& cc, std::uint64_t seed, double t, std::int64_t b, bool f,
                                      ReplicaExchange& x, const std::function<SharedStart()>& make,
                                      std::vector<float>& heights, int ny) {
    { cc.active() } -> std::convertible_to<bool>;
    { c.share_start(make) } -> std::same_as<SharedStart>;
    { c.anneal_seed(seed) } -> std::convertible_to<std::uint64_t>;
    { c.stage_temperature_scale() } -> std::convertible_to<double>;
    { cc.exchange_every(ny, ny, ny) } -> std::convertible_to<std::int64_t>;
    { c.common_temperature(t) } -> std::convertible_to<double>;
    { c.common_budget(b) } -> std::convertible_to<std::int64_t>;
    { c.any(f) } -> std::convertible_to<bool>;
    { c.exchange(x) } -> std::convertible_to<bool>;
    { cc.shares_surface() } -> std::convertible_to<bool>;
    { cc.merge_every(ny, ny, ny) } -> std::convertible_to<std::int64_t>;
    { cc.centre_rows(ny) } -> std::same_as<std::pair<int, int>>;
    c.merge(heights, heights);
};
static_assert(ReplicaCoordinator<SingleReplica>);

}  // namespace freeform
