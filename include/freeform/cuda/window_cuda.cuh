#pragma once
// A window of moves evaluated on the GPU from selection to sums (docs/cuda.md, "Towards
// designs on the GPU"): the device form of WindowEvaluation::select_flat, retrace and
// sum_atomic (trace/window.hpp), with the same kernels (trace/window_kernel.hpp). The
// flat ray/cell index and the maintained records are kept on the device; a window sends
// up its moves and their patches and gets back each proposal's compact change.
//
// What still runs on the host: the scan of the slots' counts (a download, a scan, an
// upload), the sort of each proposal's touched cells, and the planning of the slots
// (window_slots). The state is copied up whole after each commit (upload_state); a
// commit on the device (records and index updated in place) is the next step.
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
#include "../trace/window_kernel.hpp"
#include "exec_cuda.cuh"
#include "trace_cuda.cuh"

namespace freeform::cuda {

class DeviceWindowEvaluation {
public:
    // Copies the maintained state to the device: the flat ray/cell index (host arrays:
    // `cells` surface cells, `rays` rays) and the records. Call after every commit.
    void upload_state(const RayCellIndexView& index, std::int64_t cells, std::int64_t rays,
                      std::span<const RayRecord> records) {
        const auto put = [](auto& buffer, const auto* host, std::int64_t n) {
            using T = std::remove_cvref_t<decltype(*host)>;
            buffer.resize(std::size_t(std::max<std::int64_t>(n, 1)));
            buffer.upload(std::span<const T>(host, std::size_t(n)));
        };
        put(cell_begin_, index.cell_begin, cells + 1);
        put(cell_rays_, index.cell_rays, index.cell_begin[cells]);
        put(ray_begin_, index.ray_begin, rays + 1);
        put(crossings_, index.crossings, index.ray_begin[rays]);
        put(maintained_, records.data(), std::int64_t(records.size()));
        index_ = {cell_begin_.data(), cell_rays_.data(), ray_begin_.data(), crossings_.data(), index.row};
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
        WindowSelectKernel select{index_, patches_.data(), slot_proposal_.data(), reach_.data()};
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

    // The state (upload_state).
    DeviceBuffer<std::int64_t> cell_begin_, ray_begin_;
    DeviceBuffer<std::int32_t> cell_rays_;
    DeviceBuffer<CellCrossing> crossings_;
    DeviceBuffer<RayRecord> maintained_;
    RayCellIndexView index_;
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

}  // namespace freeform::cuda
