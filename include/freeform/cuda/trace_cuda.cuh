#pragma once
// The height-field tracer on the GPU (docs/architecture.md §5). The surface, the aperture mask and
// the rays live in device memory; every ray is traced by trace_heightfield_ray, the same
// FREEFORM_HD kernel HeightfieldTracer runs on the CPU, through for_each(exec::cuda, ...),
// and deposited with the same `deposit` into a fixed-point histogram with 64-bit atomics.
// Fixed-point sums are exact and order-free, so the GPU histogram equals the CPU one bit
// for bit, provided neither side contracts a*b+c into a fused multiply-add: compile the
// CUDA side with --fmad=false and the host side without FMA contraction (docs/cuda.md).
//
// Compile with nvcc (--extended-lambda is not needed by this header, but by lambdas passed
// to for_each(exec::cuda, ...)); include <freeform/cuda.hpp> from mixed code.
#include <cuda_runtime.h>

#include <array>
#include <atomic>
#include <cstddef>
#include <cstdint>
#include <span>
#include <string>
#include <string_view>
#include <type_traits>
#include <utility>
#include <vector>

#include "../core/error.hpp"
#include "../core/exec.hpp"
#include "../core/fixed_point.hpp"
#include "../core/hd.hpp"
#include "../core/histogram.hpp"
#include "../scene/rays.hpp"
#include "../surface/heightmap.hpp"
#include "../surface/overlay.hpp"
#include "../trace/heightfield.hpp"
#include "../trace/heightfield_kernel.hpp"
#include "../trace/path.hpp"
#include "../trace/tracer.hpp"
#include "../trace/window_kernel.hpp"
#include "exec_cuda.cuh"
#include "kernels.hpp"

namespace freeform::cuda {

// An array in device memory (cudaMalloc, never managed memory), freed on destruction.
// Copies are explicit (upload/download) and synchronous with respect to the host unless
// a stream is given, in which case the caller synchronises before touching the data.
template <class T>
class DeviceBuffer {
    static_assert(std::is_trivially_copyable_v<T>, "DeviceBuffer holds plain data copied byte by byte");

public:
    DeviceBuffer() = default;
    explicit DeviceBuffer(std::size_t n) { resize(n); }
    explicit DeviceBuffer(std::span<const T> host) {
        resize(host.size());
        upload(host);
    }
    DeviceBuffer(const DeviceBuffer&) = delete;
    DeviceBuffer& operator=(const DeviceBuffer&) = delete;
    DeviceBuffer(DeviceBuffer&& o) noexcept
        : ptr_(std::exchange(o.ptr_, nullptr)), size_(std::exchange(o.size_, 0)),
          capacity_(std::exchange(o.capacity_, 0)) {}
    DeviceBuffer& operator=(DeviceBuffer&& o) noexcept {
        std::swap(ptr_, o.ptr_);
        std::swap(size_, o.size_);
        std::swap(capacity_, o.capacity_);
        return *this;
    }
    ~DeviceBuffer() {
        if (ptr_) (void)cudaFree(ptr_);  // a destructor cannot report; a failed free leaks
    }

    T* data() { return ptr_; }
    const T* data() const { return ptr_; }
    std::size_t size() const { return size_; }
    bool empty() const { return size_ == 0; }

    // Sets the size to n; the contents are undefined afterwards. Memory is reallocated
    // only when n exceeds what the buffer ever held, so per-call scratch does not churn.
    void resize(std::size_t n) {
        if (n > capacity_) {
            T* p = nullptr;
            check(cudaMalloc(reinterpret_cast<void**>(&p), n * sizeof(T)),
                  "DeviceBuffer: cudaMalloc of " + std::to_string(n * sizeof(T)) + " bytes");
            if (ptr_) (void)cudaFree(ptr_);
            ptr_ = p;
            capacity_ = n;
        }
        size_ = n;
    }

    // Copies host[0, host.size()) to elements [offset, offset + host.size()).
    void upload(std::span<const T> host, std::size_t offset = 0, cudaStream_t stream = nullptr) {
        if (host.empty()) return;
        require(offset, host.size(), "upload");
        check(cudaMemcpyAsync(ptr_ + offset, host.data(), host.size_bytes(), cudaMemcpyHostToDevice, stream),
              "DeviceBuffer: upload");
        if (!stream) check(cudaStreamSynchronize(stream), "DeviceBuffer: upload");
    }
    // Copies elements [offset, offset + host.size()) to host.
    void download(std::span<T> host, std::size_t offset = 0, cudaStream_t stream = nullptr) const {
        if (host.empty()) return;
        require(offset, host.size(), "download");
        check(cudaMemcpyAsync(host.data(), ptr_ + offset, host.size_bytes(), cudaMemcpyDeviceToHost, stream),
              "DeviceBuffer: download");
        if (!stream) check(cudaStreamSynchronize(stream), "DeviceBuffer: download");
    }
    std::vector<T> to_host() const {
        std::vector<T> v(size_);
        download(v);
        return v;
    }
    // Sets every byte to zero (for integers and floats: every element to 0).
    void zero(cudaStream_t stream = nullptr) {
        if (size_ == 0) return;
        check(cudaMemsetAsync(ptr_, 0, size_ * sizeof(T), stream), "DeviceBuffer: zero");
        if (!stream) check(cudaStreamSynchronize(stream), "DeviceBuffer: zero");
    }

private:
    void require(std::size_t offset, std::size_t count, const char* what) const {
        if (offset > size_ || count > size_ - offset)
            throw InputError(std::string("DeviceBuffer: ") + what + " of " + std::to_string(count) +
                             " elements at offset " + std::to_string(offset) + " overruns a buffer of " +
                             std::to_string(size_));
    }

    T* ptr_ = nullptr;
    std::size_t size_ = 0;
    std::size_t capacity_ = 0;
};

// Device pointers to a ray set, for kernels of one's own.
struct DeviceRays {
    const Vec3* origin = nullptr;
    const Vec3* direction = nullptr;
    const Fixed* weight = nullptr;
    std::int64_t size = 0;
};

// The height-field tracer with a device copy of the surface and the rays.
//
// With exec::cuda_t the work runs on the GPU; with exec::seq / exec::omp it runs on the
// CPU exactly as HeightfieldTracer does, so the class satisfies the Tracer concept and
// can stand in for HeightfieldTracer anywhere. The surface and the rays are referenced,
// not copied: they must outlive the tracer, and every height change must be followed by
// surface_changed() (and a new ray set by rays_changed()) before the next GPU trace.
//
// The device copy belongs to the device that was current at construction; use the
// tracer with that device current. A tracer holds scratch buffers for its GPU calls: one
// GPU call at a time per tracer (CPU calls may overlap as with HeightfieldTracer).
class DeviceHeightfieldTracer {
public:
    DeviceHeightfieldTracer(const Heightmap& surface, const RaySet& rays, const PathParams& params)
        : surface_(&surface), rays_(&rays), params_(params) {
        if (rays.direction.size() != rays.origin.size() || rays.weight.size() != rays.origin.size())
            throw InputError("DeviceHeightfieldTracer: the ray set has " + std::to_string(rays.origin.size()) +
                             " origins, " + std::to_string(rays.direction.size()) + " directions and " +
                             std::to_string(rays.weight.size()) + " weights");
        heights_ = DeviceBuffer<float>(std::span(surface.heights()));
        normals_ = DeviceBuffer<Vec3>(std::span(surface.normals()));
        if (surface.aperture() != Aperture::rect) mask_ = DeviceBuffer<std::uint8_t>(std::span(surface.cell_mask()));
        upload_rays();
        totals_.resize(std::size_t(totals_lanes) * totals_slots);
    }

    static constexpr std::string_view name() { return "heightfield-cuda"; }
    const RaySet& rays() const { return *rays_; }
    const PathParams& params() const { return params_; }
    const Heightmap& surface() const { return *surface_; }

    // The CPU tracer over the same surface, rays and physics.
    HeightfieldTracer host_tracer() const { return HeightfieldTracer(*surface_, *rays_, params_); }

    // The device copy of the surface and rays, for kernels of one's own.
    HeightfieldView device_view() const {
        HeightfieldView v = surface_->view();
        v.h = heights_.data();
        v.n = normals_.data();
        v.cell_on = mask_.empty() ? nullptr : mask_.data();
        return v;
    }
    DeviceRays device_rays() const {
        return {origin_.data(), direction_.data(), weight_.data(), std::int64_t(origin_.size())};
    }

    // Copies the heights of `patch` and the normals they affect (its normal support) to
    // the device. Call after changing the host heights (and normals) in `patch`.
    void surface_changed(const Patch& patch) {
        const Heightmap& s = *surface_;
        upload_rect(heights_, s.heights(), patch.clipped(s.nx(), s.ny()));
        upload_rect(normals_, s.normals(), s.normal_support(patch));
    }
    // Copies the whole ray set again (after the RaySet was regenerated).
    void rays_changed() { upload_rays(); }

    // Traces every ray into `out` (receiver-sized) and `totals`.
    void trace_all(exec::cuda_t policy, Histogram& out, TraceTotals& totals) const {
        check_histogram(out);
        const std::int64_t n = rays_->size();
        cells_.resize(out.cells.size());
        cells_.zero(policy.stream);
        totals_.zero(policy.stream);
        policy.synchronize = false;  // the downloads below wait for the kernel
        for_each(policy, n,
                 TraceDepositKernel<HeightfieldView>{device_view(), params_, origin_.data(), direction_.data(),
                                                     weight_.data(), cells_.data(), totals_.data()});
        static_assert(sizeof(Fixed) == sizeof(unsigned long long));
        std::array<unsigned long long, std::size_t(totals_lanes) * totals_slots> lanes{};
        check(cudaMemcpyAsync(out.cells.data(), cells_.data(), cells_.size() * sizeof(Fixed), cudaMemcpyDeviceToHost,
                              policy.stream),
              "DeviceHeightfieldTracer::trace_all: histogram download");
        check(cudaMemcpyAsync(lanes.data(), totals_.data(), sizeof(lanes), cudaMemcpyDeviceToHost, policy.stream),
              "DeviceHeightfieldTracer::trace_all: totals download");
        check(cudaStreamSynchronize(policy.stream), "DeviceHeightfieldTracer::trace_all");
        totals = fold_totals(lanes, n);
        totals.emitted = rays_->total;
    }

    // Traces the rays `ids` into `records` (records[k] belongs to ids[k]).
    void trace(exec::cuda_t policy, std::span<const std::int32_t> ids, std::span<RayRecord> records) const {
        trace_records(policy, device_view(), ids, records);
    }

    // The same against the surface as `overlay` would leave it (incremental evaluation of
    // a proposed move, surface/overlay.hpp), without changing the device surface.
    void trace(exec::cuda_t policy, std::span<const std::int32_t> ids, std::span<RayRecord> records,
               const HeightOverlay& overlay) const {
        OverlayView v = overlay_view(*surface_, overlay);
        static_cast<HeightfieldView&>(v) = device_view();
        overlay_heights_.resize(overlay.heights.size());
        overlay_normals_.resize(overlay.normals.size());
        overlay_heights_.upload(std::span(overlay.heights), 0, policy.stream);
        overlay_normals_.upload(std::span(overlay.normals), 0, policy.stream);
        v.oh = overlay_heights_.data();
        v.on = overlay_normals_.data();
        trace_records(policy, v, ids, records);
    }

    // Copies a window's moves to the device and returns their views there (device memory,
    // one per move, valid until the next call that uploads moves): the moves' heights and
    // normals go up packed, one copy each, then the views. On `policy`'s stream; the
    // caller's next synchronisation covers it.
    const OverlayView* upload_window_views(exec::cuda_t policy, std::span<const HeightOverlay> moves) const {
        std::vector<float> heights;
        std::vector<Vec3> normals;
        std::vector<std::size_t> at_height, at_normal;
        for (const HeightOverlay& o : moves) {
            at_height.push_back(heights.size()), at_normal.push_back(normals.size());
            heights.insert(heights.end(), o.heights.begin(), o.heights.end());
            normals.insert(normals.end(), o.normals.begin(), o.normals.end());
        }
        overlay_heights_.resize(std::max<std::size_t>(1, heights.size()));
        overlay_normals_.resize(std::max<std::size_t>(1, normals.size()));
        if (!heights.empty()) overlay_heights_.upload(std::span<const float>(heights), 0, policy.stream);
        if (!normals.empty()) overlay_normals_.upload(std::span<const Vec3>(normals), 0, policy.stream);
        host_views_.clear();
        overlay_views(*surface_, moves, host_views_);
        for (std::size_t p = 0; p < moves.size(); ++p) {
            static_cast<HeightfieldView&>(host_views_[p]) = device_view();
            host_views_[p].oh = overlay_heights_.data() + at_height[p];
            host_views_[p].on = overlay_normals_.data() + at_normal[p];
        }
        window_views_.resize(std::max<std::size_t>(1, host_views_.size()));
        window_views_.upload(std::span<const OverlayView>(host_views_), 0, policy.stream);
        return window_views_.data();
    }

    // A window of moves in one launch (trace/window.hpp): pair k is ray ray[k] through
    // moves[proposal[k]], its record into records[k]. The moves go up (upload_window_views),
    // then the pairs, then one kernel over the pairs.
    void trace_window(exec::cuda_t policy, std::span<const HeightOverlay> moves, std::span<const std::int32_t> proposal,
                      std::span<const std::int32_t> ray, std::span<RayRecord> records) const {
        check_window(moves.size(), proposal, ray, records);
        if (ray.empty()) return;
        const OverlayView* views = upload_window_views(policy, moves);
        window_proposals_.resize(proposal.size());
        window_proposals_.upload(proposal, 0, policy.stream);
        ids_.resize(ray.size());
        ids_.upload(ray, 0, policy.stream);
        records_.resize(ray.size());
        policy.synchronize = false;  // the download below waits for the kernel
        for_each(policy, std::int64_t(ray.size()),
                 WindowRetraceKernel<OverlayView>{views, params_, origin_.data(), direction_.data(),
                                                  window_proposals_.data(), ids_.data(), records_.data()});
        records_.download(records, 0, policy.stream);
        check(cudaStreamSynchronize(policy.stream), "DeviceHeightfieldTracer::trace_window");
    }

    // The CPU versions: HeightfieldTracer's, on the host copy of the surface.
    template <HostPolicy P>
    void trace_all(P policy, Histogram& out, TraceTotals& totals) const {
        host_tracer().trace_all(policy, out, totals);
    }
    template <HostPolicy P>
    void trace(P policy, std::span<const std::int32_t> ids, std::span<RayRecord> records) const {
        host_tracer().trace(policy, ids, records);
    }
    template <HostPolicy P>
    void trace(P policy, std::span<const std::int32_t> ids, std::span<RayRecord> records,
               const HeightOverlay& overlay) const {
        check_ids(ids, records);
        const OverlayView v = overlay_view(*surface_, overlay);
        for_each(policy, std::int64_t(ids.size()),
                 TraceRecordsKernel<OverlayView>{v, params_, rays_->origin.data(), rays_->direction.data(),
                                                 ids.data(), records.data()});
    }

    template <HostPolicy P>
    void trace_window(P policy, std::span<const HeightOverlay> moves, std::span<const std::int32_t> proposal,
                      std::span<const std::int32_t> ray, std::span<RayRecord> records) const {
        check_window(moves.size(), proposal, ray, records);
        std::vector<OverlayView> views;
        overlay_views(*surface_, moves, views);
        for_each(policy, std::int64_t(ray.size()),
                 WindowRetraceKernel<OverlayView>{views.data(), params_, rays_->origin.data(), rays_->direction.data(),
                                                  proposal.data(), ray.data(), records.data()});
    }

private:
    // As check_ids, and every pair's proposal must be one of the window's moves.
    void check_window(std::size_t moves, std::span<const std::int32_t> proposal, std::span<const std::int32_t> ray,
                      std::span<RayRecord> records) const {
        if (proposal.size() != ray.size())
            throw InputError("DeviceHeightfieldTracer::trace_window: " + std::to_string(proposal.size()) +
                             " proposals for " + std::to_string(ray.size()) + " rays");
        for (const std::int32_t p : proposal)
            if (p < 0 || std::size_t(p) >= moves)
                throw InputError("DeviceHeightfieldTracer::trace_window: proposal " + std::to_string(p) +
                                 " of a window of " + std::to_string(moves) + " moves");
        check_ids(ray, records);
    }

    void upload_rays() {
        const RaySet& r = *rays_;
        origin_.resize(r.origin.size());
        direction_.resize(r.direction.size());
        weight_.resize(r.weight.size());
        origin_.upload(std::span(r.origin));
        direction_.upload(std::span(r.direction));
        weight_.upload(std::span(r.weight));
    }

    // Copies the rows of `p` (vertex indices, clipped) of a row-major nx-wide grid.
    template <class T>
    void upload_rect(DeviceBuffer<T>& dst, const std::vector<T>& src, const Patch& p) {
        if (p.empty()) return;
        const std::size_t nx = std::size_t(surface_->nx());
        const std::size_t first = std::size_t(p.j0) * nx + std::size_t(p.i0);
        check(cudaMemcpy2D(dst.data() + first, nx * sizeof(T), src.data() + first, nx * sizeof(T),
                           std::size_t(p.width()) * sizeof(T), std::size_t(p.height()), cudaMemcpyHostToDevice),
              "DeviceHeightfieldTracer::surface_changed");
    }

    void check_histogram(const Histogram& out) const {
        const ReceiverView& rv = params_.receiver;
        if (out.width != rv.width || out.height != rv.height ||
            out.cells.size() != std::size_t(rv.width) * std::size_t(rv.height))
            throw InputError("DeviceHeightfieldTracer::trace_all: histogram is " + std::to_string(out.width) + " x " +
                             std::to_string(out.height) + ", the receiver is " + std::to_string(rv.width) + " x " +
                             std::to_string(rv.height));
    }

    // Bad ids would read outside the device arrays and poison the CUDA context; they are
    // rejected on the host first.
    void check_ids(std::span<const std::int32_t> ids, std::span<RayRecord> records) const {
        if (records.size() != ids.size())
            throw InputError("DeviceHeightfieldTracer::trace: " + std::to_string(ids.size()) + " ids but " +
                             std::to_string(records.size()) + " records");
        const std::int64_t n = rays_->size();
        for (const std::int32_t id : ids)
            if (id < 0 || id >= n)
                throw InputError("DeviceHeightfieldTracer::trace: ray id " + std::to_string(id) +
                                 " is outside the ray set [0, " + std::to_string(n) + ")");
    }

    template <class View>
    void trace_records(exec::cuda_t policy, const View& view, std::span<const std::int32_t> ids,
                       std::span<RayRecord> records) const {
        check_ids(ids, records);
        if (ids.empty()) return;
        ids_.resize(ids.size());
        records_.resize(ids.size());
        ids_.upload(ids, 0, policy.stream);
        policy.synchronize = false;  // the download below waits for the kernel
        for_each(policy, std::int64_t(ids.size()),
                 TraceRecordsKernel<View>{view, params_, origin_.data(), direction_.data(), ids_.data(),
                                          records_.data()});
        records_.download(records, 0, policy.stream);
        check(cudaStreamSynchronize(policy.stream), "DeviceHeightfieldTracer::trace");
    }

    const Heightmap* surface_;
    const RaySet* rays_;
    PathParams params_;
    DeviceBuffer<float> heights_;
    DeviceBuffer<Vec3> normals_;
    DeviceBuffer<std::uint8_t> mask_;  // empty for a rectangular aperture
    DeviceBuffer<Vec3> origin_, direction_;
    DeviceBuffer<Fixed> weight_;
    // Scratch of the GPU calls (hence mutable: the calls are logically const).
    mutable DeviceBuffer<unsigned long long> cells_, totals_;
    mutable DeviceBuffer<std::int32_t> ids_;
    mutable DeviceBuffer<RayRecord> records_;
    mutable DeviceBuffer<float> overlay_heights_;
    mutable DeviceBuffer<Vec3> overlay_normals_;
    mutable DeviceBuffer<OverlayView> window_views_;
    mutable std::vector<OverlayView> host_views_;  // upload_window_views' staging (kept: its memory reused)
    mutable DeviceBuffer<std::int32_t> window_proposals_;
};

static_assert(Tracer<DeviceHeightfieldTracer>, "DeviceHeightfieldTracer must satisfy the Tracer concept");

}  // namespace freeform::cuda
