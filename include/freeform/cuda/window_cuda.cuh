#pragma once
// A window of moves evaluated on the GPU from selection to sums (docs/cuda.md, "Towards
// designs on the GPU"): the device form of WindowEvaluation::select_flat, retrace and
// sum_atomic (trace/window.hpp), with the same kernels (trace/window_kernel.hpp). The
// flat ray/cell index and the maintained records are kept on the device; a window sends
// up its moves and their patches and gets back each proposal's compact change.
//
// The index is the slotted one (trace/index_kernel.hpp), copied up once (upload_state)
// and updated in place by commit() when a move is accepted: the accepted move's rays,
// records and crossings go up (the host evaluates it, as the annealer's window path
// does), the commit kernels do the rest. Its lists are sorted by ray id, so a window's
// pairs come in another order than the host index's: compare with a host
// SlottedRayCellIndex. What still runs on the host: the scan of the slots' counts (a
// download, a scan, an upload), the sort of each proposal's touched cells, and the
// planning of the slots (window_slots).
//
// Not yet run on a device (no session so far has had one): nvcc compiles it in CI
// (cuda_compile), and the very kernels it launches are checked bit for bit under
// exec::seq and exec::omp by tests/test_incremental.cpp. benchmarks/gpu/trace_bench
// compares its changes with the host's on a device.
#include <algorithm>
#include <cstdint>
#include <numeric>
#include <span>
#include <type_traits>
#include <vector>

#include <cuda_runtime.h>

#include "../core/exec.hpp"
#include "../trace/index_kernel.hpp"
#include "../trace/window_backend.hpp"
#include "../trace/window_kernel.hpp"
#include "exec_cuda.cuh"
#include "trace_cuda.cuh"

namespace freeform::cuda {

class DeviceWindowEvaluation {
public:
    // Copies the maintained state to the device: the slotted ray/cell index (its pools'
    // spare room included) and the records. Once, and again when commit() fails.
    void upload_state(const SlottedRayCellIndex& index, std::span<const RayRecord> records) {
        const auto put = [](auto& buffer, const auto& host) {
            using T = typename std::remove_cvref_t<decltype(host)>::value_type;
            buffer.resize(std::max<std::size_t>(host.size(), 1));
            buffer.upload(std::span<const T>(host));
        };
        put(cell_begin_, index.cell_begin), put(cell_count_, index.cell_count), put(cell_room_, index.cell_room);
        put(cell_rays_, index.cell_rays), put(ray_begin_, index.ray_begin), put(ray_count_, index.ray_count);
        put(ray_room_, index.ray_room), put(crossings_, index.crossings), put(used_, index.used);
        put(maintained_, std::vector<RayRecord>(records.begin(), records.end()));
        const auto cells = index.cell_begin.size();
        dirty_mark_.resize(std::max<std::size_t>(cells, 1)), added_.resize(std::max<std::size_t>(cells, 1));
        dirty_mark_.zero(), added_.zero();
        dirty_.resize(std::max<std::size_t>(cells, 1)), dirty_count_.resize(1), overflow_.resize(1);
        index_ = {cell_begin_.data(),
                  cell_count_.data(),
                  cell_room_.data(),
                  cell_rays_.data(),
                  ray_begin_.data(),
                  ray_count_.data(),
                  ray_room_.data(),
                  crossings_.data(),
                  index.row,
                  used_.data(),
                  used_.data() + 1,
                  std::int64_t(index.cell_rays.size()),
                  std::int64_t(index.crossings.size())};
    }

    // Commits an accepted move's change (its rays, their new records and crossings: host
    // arrays as TracePart holds them) to the device's index and records with the commit
    // kernels (trace/index_kernel.hpp). False when a pool ran out of room: then call
    // upload_state with the host's index.
    bool commit(exec::cuda_t policy, std::span<const std::int32_t> rays, std::span<const RayRecord> records,
                std::span<const std::int32_t> crossing_begin, std::span<const CellCrossing> crossings) {
        policy.synchronize = false;
        upload(change_rays_, rays, policy), upload(change_records_, records, policy);
        upload(change_begin_, crossing_begin, policy), upload(change_crossings_, crossings, policy);
        const IndexChangeView change{change_rays_.data(), change_records_.data(), change_begin_.data(),
                                     change_crossings_.data()};
        const IndexCommitScratch s{dirty_mark_.data(), added_.data(), dirty_.data(), dirty_count_.data(),
                                   overflow_.data()};
        dirty_count_.zero(policy.stream), overflow_.zero(policy.stream);
        const auto n = std::int64_t(rays.size());
        for_each(policy, n, IndexUnlistKernel{index_, change, s});
        unsigned long long dirty = 0;
        dirty_count_.download(std::span(&dirty, 1), 0, policy.stream);
        check(cudaStreamSynchronize(policy.stream), "DeviceWindowEvaluation::commit: dirty cells");
        for_each(policy, std::int64_t(dirty), IndexGrowKernel{index_, s});
        for_each(policy, n, IndexAppendKernel{index_, change, s});
        for_each(policy, std::int64_t(dirty), IndexSettleKernel{index_, s});
        for_each(policy, n, IndexStoreKernel{index_, change, maintained_.data(), s.overflow});
        unsigned int overflow = 0;
        overflow_.download(std::span(&overflow, 1), 0, policy.stream);
        check(cudaStreamSynchronize(policy.stream), "DeviceWindowEvaluation::commit");
        return overflow == 0;
    }

    // Evaluates `moves` against the uploaded state: `patches` and `slot_proposal` as
    // window_slots makes them, `pad` the surface's rounding allowance
    // (hf_detail::grid_of(surface).z_pad). Afterwards change(p) is proposal p's change.
    void evaluate(exec::cuda_t policy, const DeviceHeightfieldTracer& tracer, std::span<const HeightOverlay> moves,
                  std::span<const WindowPatch> patches, std::span<const std::int32_t> slot_proposal, float pad) {
        const std::size_t n = moves.size();
        const auto slots = std::int64_t(slot_proposal.size());
        policy.synchronize = false;  // the downloads wait
        const OverlayView* views = tracer.upload_window_views(policy, moves);
        upload(patches_, patches, policy);
        upload(slot_proposal_, slot_proposal, policy);
        reach_.resize(std::size_t(std::max<std::int64_t>(slots, 1)));
        for_each(policy, slots,
                 WindowReachKernel<OverlayView>{tracer.device_view(), views, patches_.data(), slot_proposal_.data(),
                                                pad, reach_.data()});
        // Each slot's rays counted, the counts scanned on the host, the pairs written.
        WindowSelectKernel select{index_.selection(), patches_.data(), slot_proposal_.data(), reach_.data()};
        counts_.resize(std::size_t(std::max<std::int64_t>(slots, 1)));
        select.count = counts_.data();
        for_each(policy, slots, select);
        host_offset_.resize(std::size_t(slots) + 1);
        counts_.download(std::span(host_offset_).first(std::size_t(slots)), 0, policy.stream);
        check(cudaStreamSynchronize(policy.stream), "DeviceWindowEvaluation: slot counts");
        host_offset_.back() = 0;
        std::exclusive_scan(host_offset_.begin(), host_offset_.end(), host_offset_.begin(), std::int64_t(0));
        pairs_ = std::size_t(host_offset_.back());
        upload(offsets_, std::span<const std::int64_t>(host_offset_), policy);
        proposal_.resize(std::max<std::size_t>(pairs_, 1));
        ray_.resize(std::max<std::size_t>(pairs_, 1));
        select.offset = offsets_.data(), select.proposal = proposal_.data(), select.ray = ray_.data();
        for_each(policy, slots, select);
        // Every pair retraced through its move, its change worked out and summed.
        records_.resize(std::max<std::size_t>(pairs_, 1));
        for_each(policy, std::int64_t(pairs_),
                 WindowRetraceKernel<OverlayView>{views, tracer.params(), tracer.device_rays().origin,
                                                  tracer.device_rays().direction, proposal_.data(), ray_.data(),
                                                  records_.data()});
        pair_changes_.resize(std::max<std::size_t>(pairs_, 1));
        for_each(policy, std::int64_t(pairs_),
                 WindowAccountKernel{tracer.params().receiver, ray_.data(), records_.data(), maintained_.data(),
                                     tracer.device_rays().weight, pair_changes_.data()});
        sum(policy, tracer, n, patches);
    }

    std::size_t size() const { return changes_.size(); }
    const WindowChange& change(std::size_t p) const { return changes_[p]; }
    std::size_t pairs() const { return pairs_; }
    // The pairs (for checks against the host's selection): per pair, proposal and ray.
    void download_pairs(std::vector<std::int32_t>& proposal, std::vector<std::int32_t>& ray) const {
        proposal.resize(pairs_), ray.resize(pairs_);
        proposal_.download(proposal), ray_.download(ray);
    }

private:
    template <class T>
    static void upload(DeviceBuffer<T>& buffer, std::span<const T> host, exec::cuda_t policy) {
        buffer.resize(std::max<std::size_t>(host.size(), 1));
        buffer.upload(host, 0, policy.stream);
    }

    // The deposit of every pair's change into its proposal's dense change, the touched
    // cells brought back and sorted, their values gathered (and the dense change cleared).
    void sum(exec::cuda_t policy, const DeviceHeightfieldTracer& tracer, std::size_t n,
             std::span<const WindowPatch> patches) {
        const ReceiverView& rv = tracer.params().receiver;
        const std::int64_t cells = std::int64_t(rv.width) * rv.height;
        const std::size_t dense = n * std::size_t(cells);
        if (sums_.size() < dense) {  // kept zero between windows (the gather clears what it reads)
            sums_.resize(dense), claimed_.resize(dense);
            sums_.zero(policy.stream), claimed_.zero(policy.stream);
        }
        host_list_begin_.resize(n);
        for (std::size_t p = 0; p < n; ++p) host_list_begin_[p] = 8 * host_offset_[std::size_t(patches[p].slot)];
        upload(list_begin_, std::span<const std::int64_t>(host_list_begin_), policy);
        listed_.resize(std::max<std::size_t>(n, 1)), moved_.resize(std::max<std::size_t>(n, 1));
        status_.resize(std::max<std::size_t>(n * weight_slots, 1));
        listed_.zero(policy.stream), moved_.zero(policy.stream), status_.zero(policy.stream);
        touched_.resize(std::max<std::size_t>(8 * pairs_, 1));
        for_each(
            policy, std::int64_t(pairs_),
            WindowDepositKernel{proposal_.data(), pair_changes_.data(), cells, sums_.data(), claimed_.data(),
                                list_begin_.data(), listed_.data(), touched_.data(), status_.data(), moved_.data()});
        host_listed_.resize(n), host_moved_.resize(n), host_status_.resize(n * weight_slots);
        listed_.download(std::span(host_listed_), 0, policy.stream);
        moved_.download(std::span(host_moved_), 0, policy.stream);
        status_.download(std::span(host_status_), 0, policy.stream);
        check(cudaStreamSynchronize(policy.stream), "DeviceWindowEvaluation: touched counts");
        host_touched_.resize(8 * pairs_);
        for (std::size_t p = 0; p < n; ++p)
            touched_.download(
                std::span(host_touched_).subspan(std::size_t(host_list_begin_[p]), std::size_t(host_listed_[p])),
                std::size_t(host_list_begin_[p]), policy.stream);
        check(cudaStreamSynchronize(policy.stream), "DeviceWindowEvaluation: touched cells");
        pack_touched(host_touched_, host_list_begin_, host_listed_, entry_proposal_, entry_cell_);
        upload(device_entry_proposal_, std::span<const std::int32_t>(entry_proposal_), policy);
        upload(device_entry_cell_, std::span<const std::int32_t>(entry_cell_), policy);
        entry_values_.resize(std::max<std::size_t>(entry_cell_.size(), 1));
        for_each(policy, std::int64_t(entry_cell_.size()),
                 WindowGatherKernel{device_entry_proposal_.data(), device_entry_cell_.data(), cells, sums_.data(),
                                    claimed_.data(), entry_values_.data()});
        host_values_.resize(entry_cell_.size());
        entry_values_.download(std::span(host_values_), 0, policy.stream);
        check(cudaStreamSynchronize(policy.stream), "DeviceWindowEvaluation: values");
        unpack_changes(host_listed_, entry_cell_, host_values_, host_status_, host_moved_, changes_);
    }

    // The state (upload_state, commit) and the commit's scratch.
    DeviceBuffer<std::int64_t> cell_begin_, ray_begin_;
    DeviceBuffer<std::int32_t> cell_count_, cell_room_, cell_rays_, ray_count_, ray_room_;
    DeviceBuffer<CellCrossing> crossings_;
    DeviceBuffer<unsigned long long> used_, dirty_count_;
    DeviceBuffer<RayRecord> maintained_;
    SlottedIndexView index_;
    DeviceBuffer<unsigned int> dirty_mark_, added_, overflow_;
    DeviceBuffer<std::int32_t> dirty_, change_rays_, change_begin_;
    DeviceBuffer<RayRecord> change_records_;
    DeviceBuffer<CellCrossing> change_crossings_;
    // A window's, on the device and their host copies; kept from window to window.
    DeviceBuffer<WindowPatch> patches_;
    DeviceBuffer<std::int32_t> slot_proposal_, proposal_, ray_, touched_, device_entry_proposal_, device_entry_cell_;
    DeviceBuffer<CellReach> reach_;
    DeviceBuffer<std::int64_t> counts_, offsets_, list_begin_;
    DeviceBuffer<RayRecord> records_;
    DeviceBuffer<PairChange> pair_changes_;
    DeviceBuffer<unsigned long long> sums_, listed_, status_, moved_;
    DeviceBuffer<unsigned int> claimed_;
    DeviceBuffer<Fixed> entry_values_;
    std::vector<std::int64_t> host_offset_, host_list_begin_;
    std::vector<unsigned long long> host_listed_, host_moved_, host_status_;
    std::vector<std::int32_t> host_touched_, entry_proposal_, entry_cell_;
    std::vector<Fixed> host_values_;
    std::vector<WindowChange> changes_;
    std::size_t pairs_ = 0;
};

// A design's windows on the device: the WindowBackend (trace/window_backend.hpp) that
// CopiedStateWindowEvaluator (trace/window.hpp) drives, so that SurfaceProblem's
// speculative windows run here. It keeps its own device copy of the surface (a
// DeviceHeightfieldTracer over the problem's heightmap and rays, which must outlive it),
// updated with each committed move's heights and copied whole with the state.
class DeviceWindowBackend final : public WindowBackend {
public:
    DeviceWindowBackend(const Heightmap& surface, const RaySet& rays, const PathParams& params,
                        exec::cuda_t policy = {})
        : tracer_(surface, rays, params), policy_(policy) {}

    void upload_state(const IncrementalTrace&, const SlottedRayCellIndex& index,
                      std::span<const RayRecord> records) override {
        tracer_.surface_changed(tracer_.surface().full_patch());
        window_.upload_state(index, records);
    }
    void surface_changed(const Patch& patch) override { tracer_.surface_changed(patch); }
    void evaluate(const IncrementalTrace&, std::span<const HeightOverlay> moves, std::span<const WindowPatch> patches,
                  std::span<const std::int32_t> slot_proposal, float pad) override {
        window_.evaluate(policy_, tracer_, moves, patches, slot_proposal, pad);
    }
    const WindowChange& change(std::size_t p) const override { return window_.change(p); }
    bool commit(std::span<const std::int32_t> rays, std::span<const RayRecord> records,
                std::span<const std::int32_t> begin, std::span<const CellCrossing> crossings) override {
        return window_.commit(policy_, rays, records, begin, crossings);
    }

private:
    DeviceHeightfieldTracer tracer_;
    DeviceWindowEvaluation window_;
    exec::cuda_t policy_;
};

}  // namespace freeform::cuda
