#pragma once
// A window of proposed moves evaluated together: the batch logic of a design on the GPU
// (docs/cuda.md, "Towards designs on the GPU"), run here under exec::seq and exec::omp so
// that every CPU build tests it against the per-move evaluation.
//
// The annealer's speculative windows judge several proposals against the same state
// (anneal/annealer.hpp). IncrementalTrace::evaluate does that one proposal at a time; a
// GPU must do a whole window in one launch to pay for it. So the proposals' rays are
// flattened into (proposal, ray) pairs, the rays each proposal's move can reach, selected
// exactly as evaluate() selects them. One kernel call (for_each over the pairs: a thread
// per pair on the device) retraces every pair's ray through its own proposal's overlay.
// Each proposal's change of the histogram and of the weight per status is then summed
// from its pairs' old and new records (WindowChange). Those sums are of fixed-point
// integers (core/fixed_point.hpp), so their order does not matter: the change equals
// evaluate()'s bit for bit whatever the policy or thread count (tests/
// test_incremental.cpp), and the image terms, integer sums too (objective/
// image_terms.hpp), give every proposal the same objective.
//
// What this does not do yet: the selection and the adding up of each proposal's pairs
// run on the host (on the device they would be the ray/cell index's lookups and
// fixed-point atomics into each proposal's cells, docs/cuda.md), and the cells each ray
// crosses are not collected (a proposal that is accepted is evaluated again by
// evaluate(), whose change commit() needs). DeviceHeightfieldTracer::trace_window
// retraces the pairs on the GPU.
#include <array>
#include <cstdint>
#include <span>
#include <vector>

#include "../core/exec.hpp"
#include "../surface/overlay.hpp"
#include "incremental.hpp"
#include "window_kernel.hpp"

namespace freeform {

// One proposal's change in a window: what IncrementalTrace::evaluate's TraceChange holds
// but for the records and cells, compactly (the cells it changes, not a receiver-sized
// array: a window holds many).
struct WindowChange {
    std::vector<std::int32_t> cells;                 // histogram cells whose value changes, in the order first touched
    std::vector<Fixed> values;                       // their changes
    std::array<Fixed, weight_slots> status_delta{};  // change of weight per slot (RayStatus, Fresnel)
    std::int64_t rays_moved = 0;                     // rays whose record changed
};

// One window's evaluation, reused from window to window (it keeps its memory). In three
// steps, so that the middle one can run elsewhere (DeviceHeightfieldTracer::trace_window
// retraces the same pairs on the GPU): select() lists the pairs, retrace() fills their
// records, sum() adds each proposal's change up. Its scratch is one selection's (the
// ray marks) and one receiver-sized delta, whatever the window's size.
class WindowEvaluation {
public:
    // All three steps on the host. Nothing changes in `trace`.
    template <HostPolicy P>
    void evaluate(P policy, const IncrementalTrace& trace, std::span<const HeightOverlay> moves) {
        select(trace, moves);
        retrace(policy, trace, moves);
        sum(policy, trace);
    }

    // Lists the (proposal, ray) pairs of `moves`, proposal by proposal: each move's rays as
    // evaluate() selects them, in its order.
    void select(const IncrementalTrace& trace, std::span<const HeightOverlay> moves) {
        const std::size_t n = moves.size();
        proposal_.clear();
        ray_.clear();
        begin_.assign(1, 0);
        for (std::size_t p = 0; p < n; ++p) {
            trace.select_move_rays(moves[p], scratch_);
            for (const std::int32_t r : scratch_.rays) proposal_.push_back(std::int32_t(p)), ray_.push_back(r);
            begin_.push_back(ray_.size());
        }
        records_.resize(ray_.size());
        changes_.resize(n);
    }

    // Retraces every pair's ray through its move's overlay on the host: one for_each over
    // the pairs, the kernel a device runs.
    template <HostPolicy P>
    void retrace(P policy, const IncrementalTrace& trace, std::span<const HeightOverlay> moves) {
        overlay_views(trace.surface(), moves, views_);
        const RaySet& rays = trace.rays();
        for_each(
            policy, std::int64_t(ray_.size()),
            WindowRetraceKernel<OverlayView>{views_.data(), trace.params(), rays.origin.data(), rays.direction.data(),
                                             proposal_.data(), ray_.data(), records_.data()});
    }

    // Adds each proposal's change up from its pairs' records, as evaluate() accounts its
    // rays, into change(p): a kernel over the pairs works out each ray's change
    // (WindowAccountKernel), then each proposal's are added up in exact integers.
    template <HostPolicy P>
    void sum(P policy, const IncrementalTrace& trace) {
        pair_changes_.resize(ray_.size());
        for_each(policy, std::int64_t(ray_.size()),
                 WindowAccountKernel{trace.params().receiver, ray_.data(), records_.data(), trace.records().data(),
                                     trace.rays().weight.data(), pair_changes_.data()});
        const auto cells = std::size_t(trace.receiver_width()) * std::size_t(trace.receiver_height());
        if (delta_.value.size() != cells) delta_.resize(cells);
        for (std::size_t p = 0; p + 1 < begin_.size(); ++p) {
            WindowChange& c = changes_[p];
            c.status_delta.fill(0);
            c.rays_moved = 0;
            for (std::size_t k = begin_[p]; k < begin_[p + 1]; ++k) {
                const PairChange& pc = pair_changes_[k];
                if (!pc.moved) continue;
                ++c.rays_moved;
                account_weight(c.status_delta, pc.status_before, pc.weight, pc.before, -1);
                account_weight(c.status_delta, pc.status_now, pc.weight, pc.now);
                for (int j = 0; j < 8; ++j)
                    if (pc.amount[j] != 0) delta_.add(pc.cell[j], pc.amount[j]);
            }
            c.cells.clear();
            c.values.clear();
            delta_.drain([&](std::int32_t cell, Fixed v) { c.cells.push_back(cell), c.values.push_back(v); });
        }
    }

    std::size_t size() const { return changes_.size(); }
    const WindowChange& change(std::size_t p) const { return changes_[p]; }
    // Proposal p's rays, in evaluate()'s order.
    std::span<const std::int32_t> rays_of(std::size_t p) const {
        return std::span(ray_).subspan(begin_[p], begin_[p + 1] - begin_[p]);
    }
    std::size_t pairs() const { return ray_.size(); }                      // rays retraced, all proposals together
    std::span<const std::int32_t> proposals() const { return proposal_; }  // per pair
    std::span<const std::int32_t> rays() const { return ray_; }            // per pair
    std::span<RayRecord> records() { return records_; }                    // per pair, after retrace()

private:
    TraceChange scratch_;  // one proposal's selection
    SparseDelta delta_;    // one proposal's histogram change, drained into its WindowChange
    std::vector<WindowChange> changes_;
    std::vector<OverlayView> views_;
    std::vector<std::int32_t> proposal_, ray_;
    std::vector<std::size_t> begin_;  // proposal p's pairs: [begin_[p], begin_[p + 1])
    std::vector<RayRecord> records_;
    std::vector<PairChange> pair_changes_;  // per pair, after sum()'s kernel
};

}  // namespace freeform
