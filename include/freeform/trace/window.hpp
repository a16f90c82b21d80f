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
// Each step has two forms. select() and sum() run on the host (select() walks the
// incremental trace's own index, sum() adds each proposal's pairs up one by one), and
// are what the annealer's window path uses on the CPU. select_flat() and sum_atomic() are
// kernels only, the form a device runs: the selection reads a flat copy of the ray/cell
// index (RayCellIndexView of a FlatRayCellIndex, filled by flatten()) a thread per (proposal, cell), and
// the sums are fixed-point atomics into each proposal's dense change. Both forms give the
// same pairs in the same order and the same changes (tests/test_incremental.cpp).
// The cells each ray crosses are not collected: a proposal that is accepted is evaluated
// again by evaluate(), whose change commit() needs. DeviceHeightfieldTracer::trace_window
// retraces the pairs on the GPU.
#include <algorithm>
#include <array>
#include <cstdint>
#include <memory>
#include <numeric>
#include <span>
#include <vector>

#include "../core/exec.hpp"
#include "../surface/overlay.hpp"
#include "incremental.hpp"
#include "index_kernel.hpp"
#include "window_backend.hpp"
#include "window_kernel.hpp"

namespace freeform {

// Fills `flat` with `trace`'s present ray/cell index: each cell's rays in the order of
// its host list, each ray's crossings as stored.
inline void flatten(const IncrementalTrace& trace, FlatRayCellIndex& flat) {
    const RayCellIndex& index = trace.index();
    flat.row = trace.surface().nx() - 1;
    flat.cell_begin.assign(1, 0);
    flat.cell_rays.clear();
    for (std::int32_t c = 0; c < std::int32_t(index.cell_count()); ++c) {
        const auto& list = index.rays_of(c);
        flat.cell_rays.insert(flat.cell_rays.end(), list.begin(), list.end());
        flat.cell_begin.push_back(std::int64_t(flat.cell_rays.size()));
    }
    flat.ray_begin.assign(1, 0);
    flat.crossings.clear();
    for (std::int32_t r = 0; r < std::int32_t(index.ray_count()); ++r) {
        const auto cells = index.cells_of(r);
        flat.crossings.insert(flat.crossings.end(), cells.begin(), cells.end());
        flat.ray_begin.push_back(std::int64_t(flat.crossings.size()));
    }
}

// The slots of a window (WindowSelectKernel's threads): each proposal's patch, the cells
// its move changes, and per slot (a cell of a patch, proposal by proposal, row major) its
// proposal. A move that changes nothing has no slots.
inline void window_slots(const IncrementalTrace& trace, std::span<const HeightOverlay> moves,
                         std::vector<WindowPatch>& patches, std::vector<std::int32_t>& slot_proposal) {
    patches.resize(moves.size());
    slot_proposal.clear();
    for (std::size_t p = 0; p < moves.size(); ++p) {
        const Patch a = moves[p].empty() ? Patch{} : trace.affected_cells(moves[p]);
        patches[p] = WindowPatch{a.i0, a.j0, a.i1, a.j1, std::int64_t(slot_proposal.size())};
        slot_proposal.insert(slot_proposal.end(), std::size_t(a.count()), std::int32_t(p));
    }
}

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

    // select() as kernels over a flat index of `trace`'s (flatten() of its present
    // state): the reach of every move's cells, then each cell's rays counted, then
    // written where the counts' scan puts them. The same pairs in the same order.
    template <HostPolicy P>
    void select_flat(P policy, const IncrementalTrace& trace, const RayCellIndexView& index,
                     std::span<const HeightOverlay> moves) {
        window_slots(trace, moves, patches_, slot_proposal_);
        select_flat(policy, trace, index, moves, patches_, slot_proposal_);
    }
    // The same with the window's slots already planned (window_slots), as
    // CopiedStateWindowEvaluator plans them for any backend.
    template <HostPolicy P>
    void select_flat(P policy, const IncrementalTrace& trace, const RayCellIndexView& index,
                     std::span<const HeightOverlay> moves, std::span<const WindowPatch> patches,
                     std::span<const std::int32_t> slot_proposal) {
        const std::size_t n = moves.size();
        const auto slots = std::int64_t(slot_proposal.size());
        overlay_views(trace.surface(), moves, views_);
        const HeightfieldView base = trace.surface().view();
        reach_.resize(slot_proposal.size());
        for_each(policy, slots,
                 WindowReachKernel<OverlayView>{base, views_.data(), patches.data(), slot_proposal.data(),
                                                hf_detail::grid_of(base).z_pad, reach_.data()});
        WindowSelectKernel select{index, patches.data(), slot_proposal.data(), reach_.data()};
        slot_count_.resize(slot_proposal.size() + 1);
        select.count = slot_count_.data();
        for_each(policy, slots, select);
        // The places: an exclusive scan of the counts (one more entry: the total).
        slot_count_.back() = 0;
        std::exclusive_scan(slot_count_.begin(), slot_count_.end(), slot_count_.begin(), std::int64_t(0));
        const auto pairs = std::size_t(slot_count_.back());
        proposal_.resize(pairs);
        ray_.resize(pairs);
        select.offset = slot_count_.data();
        select.proposal = proposal_.data();
        select.ray = ray_.data();
        for_each(policy, slots, select);
        begin_.resize(n + 1);
        for (std::size_t p = 0; p < n; ++p) begin_[p] = std::size_t(slot_count_[std::size_t(patches[p].slot)]);
        begin_[n] = pairs;
        records_.resize(pairs);
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

    // sum() as kernels: each pair's change (WindowAccountKernel), added into its
    // proposal's dense change with atomics (WindowDepositKernel), each proposal's touched
    // cells sorted, their values taken out (WindowGatherKernel). The same changes, each
    // proposal's cells in increasing order. Its scratch is proposals x receiver cells.
    // `maintained`: the records the pairs' changes are taken against (default: the
    // trace's; a copy kept with a slotted index, KernelWindowEvaluator's).
    template <HostPolicy P>
    void sum_atomic(P policy, const IncrementalTrace& trace, const RayRecord* maintained = nullptr) {
        const std::size_t n = changes_.size(), pairs = ray_.size();
        pair_changes_.resize(pairs);
        for_each(policy, std::int64_t(pairs),
                 WindowAccountKernel{trace.params().receiver, ray_.data(), records_.data(),
                                     maintained != nullptr ? maintained : trace.records().data(),
                                     trace.rays().weight.data(), pair_changes_.data()});
        const auto cells = std::int64_t(trace.receiver_width()) * trace.receiver_height();
        if (sums_.size() < n * std::size_t(cells)) {  // kept zero between windows (the gather clears what it reads)
            sums_.resize(n * std::size_t(cells), 0);
            claimed_.resize(n * std::size_t(cells), 0);
        }
        list_begin_.resize(n);
        for (std::size_t p = 0; p < n; ++p) list_begin_[p] = 8 * std::int64_t(begin_[p]);
        listed_.assign(n, 0);
        touched_.resize(8 * pairs);
        status_.assign(n * weight_slots, 0);
        moved_.assign(n, 0);
        for_each(
            policy, std::int64_t(pairs),
            WindowDepositKernel{proposal_.data(), pair_changes_.data(), cells, sums_.data(), claimed_.data(),
                                list_begin_.data(), listed_.data(), touched_.data(), status_.data(), moved_.data()});
        pack_touched(touched_, list_begin_, listed_, entry_proposal_, entry_cell_);
        entry_value_.resize(entry_cell_.size());
        for_each(policy, std::int64_t(entry_cell_.size()),
                 WindowGatherKernel{entry_proposal_.data(), entry_cell_.data(), cells, sums_.data(), claimed_.data(),
                                    entry_value_.data()});
        unpack_changes(listed_, entry_cell_, entry_value_, status_, moved_, changes_);
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
    // select_flat()'s: per proposal, per slot (a cell of a proposal's patch), counts and places
    std::vector<WindowPatch> patches_;
    std::vector<std::int32_t> slot_proposal_;
    std::vector<CellReach> reach_;
    std::vector<std::int64_t> slot_count_;
    // sum_atomic()'s: dense changes and claims (proposals x cells), touched lists, totals
    std::vector<unsigned long long> sums_;
    std::vector<unsigned int> claimed_;
    std::vector<std::int64_t> list_begin_;
    std::vector<unsigned long long> listed_, status_, moved_;
    std::vector<std::int32_t> touched_, entry_proposal_, entry_cell_;
    std::vector<Fixed> entry_value_;
};

// A change's parts (a move evaluated on several threads is split, TraceChange::part)
// joined into one list of rays, records and crossings, as the commit kernels read it.
inline void pack_change(const TraceChange& change, std::vector<std::int32_t>& rays, std::vector<RayRecord>& records,
                        std::vector<std::int32_t>& begin, std::vector<CellCrossing>& crossings) {
    rays.clear(), records.clear(), begin.assign(1, 0), crossings.clear();
    for (int p = 0; p < change.split; ++p) {
        const TracePart& part = change.part(p);
        rays.insert(rays.end(), part.rays.begin(), part.rays.end());
        records.insert(records.end(), part.records.begin(), part.records.end());
        for (std::size_t k = 0; k < part.rays.size(); ++k)
            begin.push_back(std::int32_t(crossings.size()) + part.cell_begin[k + 1] - part.cell_begin[0]);
        crossings.insert(crossings.end(), part.cells.begin() + part.cell_begin[0],
                         part.cells.begin() + part.cell_begin[part.rays.size()]);
    }
}

// What evaluates a design's speculative windows (SurfaceProblem::delta_window): the host
// forms on the CPU (HostWindowEvaluator), or the kernel forms over a copy of the state kept
// apart, on a device or here (CopiedStateWindowEvaluator over a WindowBackend). The copy
// is kept current through the trace's version(): committed() is told of every commit the
// problem makes, and any other change (a rebuild, new heights) shows as a version the
// evaluator has not seen, on which the whole state is copied again.
class WindowEvaluator {
public:
    virtual ~WindowEvaluator() = default;
    // Evaluates `moves` against `trace`'s present state; change(p) afterwards.
    virtual void evaluate(const IncrementalTrace& trace, std::span<const HeightOverlay> moves) = 0;
    virtual const WindowChange& change(std::size_t p) const = 0;
    // `trace` has just committed `change`, a move whose heights changed in `heights`.
    virtual void committed(const IncrementalTrace& trace, const TraceChange& change, const Patch& heights) = 0;
};

// The host forms (WindowEvaluation::evaluate) on `threads` OpenMP threads: they read the
// trace itself, so there is no copy to keep.
class HostWindowEvaluator final : public WindowEvaluator {
public:
    explicit HostWindowEvaluator(int threads) : threads_(threads) {}
    void evaluate(const IncrementalTrace& trace, std::span<const HeightOverlay> moves) override {
        window_.evaluate(exec::omp_t{threads_}, trace, moves);
    }
    const WindowChange& change(std::size_t p) const override { return window_.change(p); }
    void committed(const IncrementalTrace&, const TraceChange&, const Patch&) override {}

private:
    int threads_;
    WindowEvaluation window_;
};

// The evaluator over a WindowBackend (trace/window_backend.hpp): it plans each window on
// the host (window_slots) and keeps the backend's copy current, by the commit kernels
// after each commit, whole after anything else.
class CopiedStateWindowEvaluator final : public WindowEvaluator {
public:
    explicit CopiedStateWindowEvaluator(std::unique_ptr<WindowBackend> backend) : backend_(std::move(backend)) {}

    void evaluate(const IncrementalTrace& trace, std::span<const HeightOverlay> moves) override {
        if (!current_ || version_ != trace.version()) copy_state(trace);
        window_slots(trace, moves, patches_, slot_proposal_);
        backend_->evaluate(trace, moves, patches_, slot_proposal_, pad_);
    }
    const WindowChange& change(std::size_t p) const override { return backend_->change(p); }

    void committed(const IncrementalTrace& trace, const TraceChange& change, const Patch& heights) override {
        if (!current_ || version_ + 1 != trace.version()) {
            current_ = false;  // copied whole at the next evaluate()
            return;
        }
        pack_change(change, rays_, records_, begin_, crossings_);
        backend_->surface_changed(heights);
        current_ = backend_->commit(rays_, records_, begin_, crossings_);
        version_ = trace.version();
        ++commits_;
    }

    std::int64_t copies() const { return copies_; }    // whole copies of the state made
    std::int64_t commits() const { return commits_; }  // commits applied by the kernels
    WindowBackend& backend() { return *backend_; }

private:
    void copy_state(const IncrementalTrace& trace) {
        flatten(trace, flat_);
        slotted_.assign(flat_);
        pad_ = hf_detail::grid_of(trace.surface().view()).z_pad;
        backend_->upload_state(trace, slotted_, trace.records());
        version_ = trace.version();
        current_ = true;
        ++copies_;
    }

    std::unique_ptr<WindowBackend> backend_;
    FlatRayCellIndex flat_;
    SlottedRayCellIndex slotted_;
    std::vector<WindowPatch> patches_;
    std::vector<std::int32_t> slot_proposal_, rays_, begin_;
    std::vector<RayRecord> records_;
    std::vector<CellCrossing> crossings_;
    float pad_ = 0;
    std::uint64_t version_ = 0;
    bool current_ = false;
    std::int64_t copies_ = 0, commits_ = 0;
};

// The backend on the host: the kernel forms (select_flat, sum_atomic, the commit kernels)
// under a host policy, over a slotted index and records of its own. What
// cuda::DeviceWindowBackend does on a device, so that a whole design run on the CPU tests
// the evaluator's bookkeeping (tests/test_incremental.cpp).
template <HostPolicy P>
class HostKernelWindowBackend final : public WindowBackend {
public:
    explicit HostKernelWindowBackend(P policy) : policy_(policy) {}

    void upload_state(const IncrementalTrace&, const SlottedRayCellIndex& index,
                      std::span<const RayRecord> records) override {
        slotted_ = index;
        records_.assign(records.begin(), records.end());
    }
    void surface_changed(const Patch&) override {}  // reads the host surface itself
    void evaluate(const IncrementalTrace& trace, std::span<const HeightOverlay> moves,
                  std::span<const WindowPatch> patches, std::span<const std::int32_t> slot_proposal, float) override {
        window_.select_flat(policy_, trace, slotted_.view().selection(), moves, patches, slot_proposal);
        window_.retrace(policy_, trace, moves);
        window_.sum_atomic(policy_, trace, records_.data());
    }
    const WindowChange& change(std::size_t p) const override { return window_.change(p); }
    bool commit(std::span<const std::int32_t> rays, std::span<const RayRecord> records,
                std::span<const std::int32_t> begin, std::span<const CellCrossing> crossings) override {
        return slotted_.commit(policy_, {rays.data(), records.data(), begin.data(), crossings.data()},
                               std::int64_t(rays.size()), records_.data());
    }

private:
    P policy_;
    WindowEvaluation window_;
    SlottedRayCellIndex slotted_;
    std::vector<RayRecord> records_;
};

}  // namespace freeform
