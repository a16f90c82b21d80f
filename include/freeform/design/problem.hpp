#pragma once
// The design problem over a surface of any material (mirror or lens), in the form the
// generic annealer expects (anneal/annealer.hpp): energy(), propose(), delta(), accept(),
// reject().
//
// A move is a Gaussian kernel (picked by a bandit from a bank) added at a vertex, held in
// an overlay; delta() retraces only the rays the move can affect (trace/incremental.hpp)
// and returns the exact change of the objective; accept() commits heights, records and
// sums; reject() only informs the bandit. delta() changes nothing visible, so several
// proposals can be evaluated concurrently (speculative parallelism, docs/architecture.md §4).
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <exception>
#include <memory>
#include <span>
#include <string>
#include <type_traits>
#include <vector>

#include "../core/rng.hpp"
#include "../objective/objective.hpp"
#include "../propose/bandit.hpp"
#include "../propose/kernel.hpp"
#include "../propose/single_vertex.hpp"
#include "../trace/incremental.hpp"
#include "../trace/window.hpp"

namespace freeform {

struct ProposalSettings {
    std::vector<KernelShape> bank;  // the arms; empty with single_vertex
    bool single_vertex = false;     // the plain baseline: move one vertex
    bool error_guided = false;      // centres drawn where light lands in the wrong amount
    // A move's amplitude is expressed as the displacement, in receiver cells, of the light
    // reflected (or refracted) at the kernel's steepest point; drawn uniformly in
    // [-s, s] with s = max_shift * sqrt(T / T_ref), never below min_shift.
    double max_shift_cells = 4.0;
    double min_shift_cells = 0.25;
    // The reach envelope's margin, in the largest proposals one vertex may take before
    // the trace is rebuilt round the new heights (reach_margin below); 0: no envelope.
    double reach_moves = 16;
};

// A kernel's amplitude per unit of light shift, in grid units: the slope of a Gaussian
// peaks at 0.6 amplitude / sigma, so moves scale by the kernel's width (propose()).
inline double kernel_width(const KernelShape& k) { return std::sqrt(k.sigma_x * k.sigma_y) / 0.6; }

// The largest height change one proposal can make at the reference temperature: the
// widest kernel of the bank at max_shift_cells (propose() below).
inline double largest_proposal(const ProposalSettings& p, double metres_per_cell_shift) {
    double width = 1;
    if (!p.single_vertex)
        for (const KernelShape& k : p.bank) width = std::max(width, kernel_width(k));
    return p.max_shift_cells * metres_per_cell_shift * width;
}

// The reach envelope's margin for these proposals (trace/incremental.hpp): room for
// p.reach_moves of the largest proposals piled on one vertex, the trace rebuilt round
// the new heights once a vertex has used half of it, so that the limits seldom bind.
// Infinite (no envelope) when reach_moves is 0.
inline double reach_margin(const ProposalSettings& p, double metres_per_cell_shift) {
    return p.reach_moves > 0 ? p.reach_moves * largest_proposal(p, metres_per_cell_shift) : INFINITY;
}

// How a problem retraces the rays a move can affect. The height-field backend traces
// against "surface + overlay" through an OverlayView: delta() changes nothing, so
// several deltas can run at once. Other backends (Embree, design/embree_incremental.hpp)
// must show the move to their acceleration structure first: they apply it, retrace and
// restore, so their deltas run one at a time.
struct HeightfieldBackend {
    static constexpr bool concurrent_deltas = true;
    // All its state is in the IncrementalTrace, which can then pass from one problem to
    // the next on the same surface (BasicSurfaceProblem's `reuse`).
    static constexpr bool stateless = true;
    static constexpr const char* name = "heightfield";
    int threads = 0;  // of the full rebuilds (a level's start, replaced heights, merges); 0: every core
    Histogram rebuild(IncrementalTrace& trace) const { return trace.rebuild(exec::omp_t{threads}); }
    void evaluate(const IncrementalTrace& trace, const HeightOverlay& o, TraceChange& change,
                  TaskPool* pool = nullptr) const {
        trace.evaluate(o, change, pool);
    }
    void committed(const Patch&) {}
};

// The reference's evaluation: every move retraces every ray (same results as the
// incremental backend, at the cost of a full trace; for comparisons and benchmarks).
struct FullRetraceBackend {
    static constexpr bool concurrent_deltas = true;
    static constexpr bool stateless = true;
    static constexpr const char* name = "full";
    int threads = 0;  // as HeightfieldBackend's
    Histogram rebuild(IncrementalTrace& trace) const { return trace.rebuild(exec::omp_t{threads}); }
    void evaluate(const IncrementalTrace& trace, const HeightOverlay& o, TraceChange& change,
                  TaskPool* pool = nullptr) const {
        trace.evaluate_all(o, change, pool);
    }
    void committed(const Patch&) {}
};

// The surface, its rays and target, the objective's terms and the moves; Backend is how
// a move's rays are retraced (HeightfieldBackend, FullRetraceBackend, or EmbreeBackend in
// design/embree_incremental.hpp).
template <class Backend = HeightfieldBackend>
class BasicSurfaceProblem {
public:
    // Deltas may run concurrently only when the backend allows it (anneal/annealer.hpp).
    static constexpr bool concurrent_deltas = Backend::concurrent_deltas;

    struct Move {
        HeightOverlay overlay;
        TraceChange change;
        ImageScratch image_scratch;
        ImageSums sums;              // image sums after the move
        std::int64_t penalty_sum = 0;  // penalty sum after the move
        int arm = -1;
        bool noop = false;
        double delta_value = 0;
        // Evaluated in a window (delta_window): `change` holds the histogram change, weights
        // and counts but not the records and cells, which accept() retraces first.
        bool from_window = false;
    };

    // `metres_per_cell_shift`: the height amplitude that moves the light by one receiver
    // cell per grid unit of kernel width (see design/designer.hpp). `reference_temperature`
    // scales amplitudes with temperature.
    //
    // `reuse`: the trace of a problem before this one on the same surface, rays and path
    // (take_trace()), which that problem kept consistent with the surface; it is moved in
    // instead of tracing every ray again. Its invariant (trace/incremental.hpp: records and
    // histogram equal a full retrace bit for bit) makes the problem the same as a rebuilt
    // one. Only for stateless backends; a trace of other rays is ignored (full rebuild).
    BasicSurfaceProblem(Heightmap& surface, const RaySet& rays, const PathParams& params, Target target,
                          ObjectiveWeights weights, const Penalties& penalties, ProposalSettings proposals,
                          AnyBandit bandit, double metres_per_cell_shift, double reference_temperature,
                          Backend backend = {}, IncrementalTrace* reuse = nullptr)
        : backend_(std::move(backend)), surface_(&surface), rays_(&rays), trace_(surface, rays, params),
          image_(std::move(target)),
          weights_(weights), penalties_(&penalties), proposals_(std::move(proposals)), bandit_(std::move(bandit)),
          unit_(metres_per_cell_shift), t_ref_(reference_temperature), row1_(surface.ny()) {
        for (const auto& s : proposals_.bank) kernels_.emplace_back(s);
        if (!proposals_.single_vertex && kernels_.empty())
            throw InputError("optimise.kernels: the kernel bank is empty");
        if constexpr (requires { requires Backend::stateless; }) {
            if (reuse && &reuse->rays() == &rays && &reuse->surface() == &surface) {
                // Its envelope, if any, was made for the problem before this one and stays
                // in force; this problem's margin takes over at the next rebuild.
                trace_ = std::move(*reuse);
                set_reach_margin();
                reset_sums(trace_.histogram());
                return;
            }
        }
        set_reach_margin();
        rebuild();
    }

    // Full recompute of every maintained quantity (level start, after restore_best).
    void rebuild() { reset_sums(backend_.rebuild(trace_)); }

    // Hands the trace to the next problem on this surface (the constructor's `reuse`);
    // this problem is not to be used afterwards.
    IncrementalTrace take_trace() { return std::move(trace_); }

    double energy() const { return value_.total; }
    const ObjectiveValue& value() const { return value_; }
    // Moves are centred only on the mesh rows [j0, j1) (domain decomposition: replicas
    // that share one surface each move their own strip; design/replicas.hpp). The whole
    // mesh by default; a strip the mesh does not have is clipped to it.
    void set_centre_rows(int j0, int j1) {
        row0_ = std::clamp(j0, 0, surface_->ny() - 1);
        row1_ = std::clamp(j1, row0_ + 1, surface_->ny());
    }
    const Heightmap& surface() const { return *surface_; }
    const IncrementalTrace& trace() const { return trace_; }
    const ImageState& image() const { return image_; }
    const AnyBandit& bandit() const { return bandit_; }
    void set_reference_temperature(double t) { t_ref_ = t; }

    Histogram histogram() const { return trace_.histogram(); }

    void propose(CounterRng& rng, double temperature, Move& m) {
        int ci, cj;
        choose_centre(rng, ci, cj);
        const double shift = std::max(proposals_.min_shift_cells,
                                      proposals_.max_shift_cells * std::sqrt(std::max(temperature, 0.0) / t_ref_));
        const double s = rng.uniform(-1.0, 1.0) * shift;
        if (proposals_.single_vertex) {
            m.arm = -1;
            apply_single_vertex(*surface_, ci, cj, float(s * unit_), m.overlay, trace_.vertex_bounds());
        } else {
            m.arm = bandit_.choose(rng);
            const double width = kernel_width(proposals_.bank[std::size_t(m.arm)]);
            apply_kernel(*surface_, kernels_[std::size_t(m.arm)], ci, cj, float(s * unit_ * width), m.overlay,
                         trace_.vertex_bounds());
        }
        m.overlay.trim(*surface_);
        m.noop = m.overlay.empty();
    }

    double delta(Move& m) const { return delta(m, nullptr); }

    // delta() with the threads of `pool` retracing the move's rays together, where the
    // backend can (the result is the same bit for bit); the annealer passes its pool
    // when it judges one proposal at a time.
    double delta(Move& m, TaskPool* pool) const {
        m.from_window = false;
        if (m.noop) {
            m.sums = image_.sums();
            m.penalty_sum = penalty_sum_;
            return m.delta_value = 0.0;
        }
        if constexpr (requires { backend_.evaluate(trace_, m.overlay, m.change, pool); })
            backend_.evaluate(trace_, m.overlay, m.change, pool);
        else
            backend_.evaluate(trace_, m.overlay, m.change);
        return judge(m);
    }

    // Window evaluation (trace/window.hpp), the batch logic of a design on a GPU, here on
    // the CPU: the annealer's speculative windows hand their moves to delta_window instead
    // of delta() one by one. The deltas, and so the design, are the same bit for bit
    // (tests/test_incremental.cpp). Off by default: on the CPU it is slower (the accepted
    // move is retraced again to commit it). Only the height-field backend has it.
    void set_window_evaluation(bool on) {
        if constexpr (std::is_same_v<Backend, HeightfieldBackend>)
            set_window_evaluator(on ? std::make_unique<HostWindowEvaluator>(backend_.threads) : nullptr);
    }
    // The same with windows evaluated by `e` (a copy of the state kept apart, on a device
    // say: cuda/window_cuda.cuh); null turns window evaluation off.
    void set_window_evaluator(std::unique_ptr<WindowEvaluator> e) {
        if constexpr (std::is_same_v<Backend, HeightfieldBackend>) evaluator_ = std::move(e);
    }
    bool window_evaluation() const { return evaluator_ != nullptr; }
    WindowEvaluator* window_evaluator() const { return evaluator_.get(); }
    // What ended window evaluation during the run: the evaluator's exception (a device
    // that failed, ran out of memory, was reset); empty when nothing did. From then on the
    // moves are judged one by one on the host, which gives the same deltas: the design
    // goes on, the same bit for bit, only slower.
    const std::string& window_failure() const { return window_failure_; }

    // The deltas of a window's moves, evaluated together: out[k] = delta(moves[k]).
    void delta_window(std::span<Move> moves, std::span<double> out) const
        requires std::is_same_v<Backend, HeightfieldBackend>
    {
        // Copied into overlays kept from window to window: assignment reuses their memory.
        std::size_t n = 0;
        for (const Move& m : moves) {
            if (m.noop) continue;
            if (n == window_moves_.size()) window_moves_.emplace_back();
            window_moves_[n++] = m.overlay;
        }
        const std::span<const HeightOverlay> changing(window_moves_.data(), n);
        try {
            evaluator_->evaluate(trace_, changing);
        } catch (const std::exception& e) {
            drop_evaluator(e);
            for (std::size_t k = 0; k < moves.size(); ++k) out[k] = delta(moves[k]);
            return;
        }
        const std::int64_t cells = std::int64_t(image_.width()) * image_.height();
        std::size_t p = 0;
        for (std::size_t k = 0; k < moves.size(); ++k) {
            Move& m = moves[k];
            if (m.noop) {
                out[k] = delta(m);
                continue;
            }
            const WindowChange& w = evaluator_->change(p++);
            m.change.reset(rays_->size(), cells);
            for (std::size_t c = 0; c < w.cells.size(); ++c) m.change.histogram.add(w.cells[c], w.values[c]);
            m.change.status_delta = w.status_delta;
            m.change.rays_moved = w.rays_moved;
            m.from_window = true;
            out[k] = judge(m);
        }
    }

    void accept(Move& m) { accept(m, nullptr); }

    // accept() with the threads of `pool` storing the parts of a move that delta() split
    // over them (the state is the same as without; the annealer passes its pool).
    void accept(Move& m, TaskPool* pool) {
        if (m.arm >= 0) bandit_.update(m.arm, std::max(0.0, -m.delta_value));
        if (m.noop) return;
        // Leaving the best state uphill: keep a copy of it first (rare at low temperature).
        if (best_is_current_ && m.delta_value > 0) {
            best_heights_ = surface_->heights();
            best_is_current_ = false;
        }
        if constexpr (std::is_same_v<Backend, HeightfieldBackend>) {
            if (m.from_window) {  // its records and cells: the same change, retraced in full
                backend_.evaluate(trace_, m.overlay, m.change, pool);
                m.from_window = false;
            }
        }
        m.overlay.commit(*surface_);
        backend_.committed(m.overlay.patch);
        trace_.commit(m.change, pool);
        pass_commit(m);
        image_.apply(m.change.histogram, m.sums);
        penalty_sum_ = m.penalty_sum;
        value_ = combine(image_.sums(), image_.target().total, Penalties::value(penalty_sum_, *surface_), weights_);
        if (trace_.reach().spent(m.overlay, surface_->nx())) recentre_reach();
    }

    // Full rebuilds of the trace that re-centred its reach envelope (accept()).
    std::int64_t reach_recentres() const { return recentres_; }

    void reject(Move& m) {
        if (m.arm >= 0) bandit_.update(m.arm, 0.0);
    }

    int sync_interval() const { return proposals_.single_vertex ? 1 << 30 : bandit_.sync_interval(); }
    void sync() {
        if (!proposals_.single_vertex) bandit_.sync();
        refresh_error_weights();
    }

    void on_new_best() {
        best_is_current_ = true;
        best_heights_.clear();
    }

    // The heights of the best state seen, or null when the current state is the best.
    const std::vector<float>* best_heights() const {
        return best_is_current_ || best_heights_.empty() ? nullptr : &best_heights_;
    }

    // Puts the best state seen back in place (if the current one is worse).
    void restore_best() {
        if (const std::vector<float>* best = best_heights()) replace_heights(*best);
    }

    // Sets the surface to `heights` (same mesh) and recomputes everything from them; the
    // state is then its own best. (`heights` may be best_heights_: they are copied first.)
    //
    // Heights that differ only inside a small box (a stage putting back its best state
    // after a few moves) are applied like an accepted move: only the rays that box can
    // affect are retraced. The state is the one a full rebuild gives, bit for bit (the
    // trace's invariant, trace/incremental.hpp; the sums are integers, the penalties are
    // recomputed in full). Under grazing light a rebuild takes seconds, since every ray
    // crosses some 45 cells; this keeps a short time budget (docs/performance.md).
    void replace_heights(const std::vector<float>& heights) {
        if (replace_inside_box(heights)) return;
        surface_->set_heights(heights);
        backend_.committed(surface_->full_patch());
        best_heights_.clear();
        rebuild();
    }

private:
    // The window evaluator's side of a commit (it keeps its copy of the state current).
    void pass_commit(const Move& m) {
        if (!evaluator_) return;
        try {
            evaluator_->committed(trace_, m.change, m.overlay.patch);
        } catch (const std::exception& e) {
            drop_evaluator(e);
        }
    }
    // Window evaluation off for the rest of the run (window_failure()); const because
    // delta_window is (the evaluator is state of the evaluation, not of the design).
    void drop_evaluator(const std::exception& e) const {
        window_failure_ = e.what();
        evaluator_.reset();
    }

    // replace_heights when the heights change inside a box of at most a quarter of the
    // vertices; false (nothing done) otherwise.
    bool replace_inside_box(const std::vector<float>& heights) {
        Move m;
        m.overlay.patch = surface_->full_patch();
        m.overlay.heights = heights;
        m.overlay.trim(*surface_);  // the box of the heights that differ, and its normals
        if (4 * m.overlay.patch.count() > surface_->full_patch().count()) return false;
        // Heights from before the envelope's last re-centring may lie outside it.
        if (!trace_.reach().holds(m.overlay, surface_->nx())) return false;
        if (!m.overlay.empty()) {
            delta(m);
            m.overlay.commit(*surface_);
            backend_.committed(m.overlay.patch);
            trace_.commit(m.change);
            pass_commit(m);
            image_.apply(m.change.histogram, m.sums);
        }
        penalty_sum_ = penalties_->full(*surface_);
        value_ = combine(image_.sums(), image_.target().total, Penalties::value(penalty_sum_, *surface_), weights_);
        best_is_current_ = true;
        best_heights_.clear();
        refresh_error_weights();
        return true;
    }

    // The reach envelope (trace/incremental.hpp) for this problem's proposals: only the
    // height-field backend's walk reports the path heights it needs.
    void set_reach_margin() {
        if constexpr (std::is_same_v<Backend, HeightfieldBackend>)
            trace_.set_reach_margin(float(reach_margin(proposals_, unit_)));
    }

    // Rebuilds the trace round the present heights. The records and histogram come out
    // as they are (the trace's invariant), so nothing else changes: not the sums, not
    // which state is the best.
    void recentre_reach() {
        (void)backend_.rebuild(trace_);
        ++recentres_;
    }

    // Every sum the problem maintains, from the irradiance of the current surface.
    void reset_sums(const Histogram& h) {
        image_.reset(h);
        penalty_sum_ = penalties_->full(*surface_);
        value_ = combine(image_.sums(), image_.target().total, Penalties::value(penalty_sum_, *surface_), weights_);
        best_is_current_ = true;
        refresh_error_weights();
    }

    void choose_centre(CounterRng& rng, int& ci, int& cj) const {
        const int nx = surface_->nx(), ny = surface_->ny();
        if (proposals_.error_guided && max_error_ > 0) {
            // Rejection sampling of rays in proportion to |R - T| where they land; the
            // kernel goes where the ray was aimed at the surface.
            for (int tries = 0; tries < 16; ++tries) {
                const auto id = std::size_t(rng.below(std::uint64_t(rays_->size())));
                const RayRecord& r = trace_.records()[id];
                const double e = r.status == RayStatus::receiver ? cell_error(r) : max_error_;
                if (rng.uniform() * max_error_ < e) {
                    const Vec3 o = rays_->origin[id], d = rays_->direction[id];
                    const float t = -o.z / d.z;
                    const double u = o.x + t * d.x, v = o.y + t * d.y;
                    ci = std::clamp(int(std::lround((u / surface_->size().x + 0.5) * (nx - 1))), 0, nx - 1);
                    cj = std::clamp(int(std::lround((v / surface_->size().y + 0.5) * (ny - 1))), 0, ny - 1);
                    if (cj >= row0_ && cj < row1_) return;
                }
            }
        }
        ci = int(rng.below(std::uint64_t(nx)));
        cj = row0_ + int(rng.below(std::uint64_t(row1_ - row0_)));
    }

    // The rest of delta() once m.change holds the move's histogram change: the image sums
    // and penalties after the move, and the objective's change.
    double judge(Move& m) const {
        m.sums = image_.evaluate(m.change.histogram, m.image_scratch);
        m.penalty_sum = penalty_sum_ + penalties_->delta(*surface_, m.overlay);
        const ObjectiveValue after =
            combine(m.sums, image_.target().total, Penalties::value(m.penalty_sum, *surface_), weights_);
        return m.delta_value = after.total - value_.total;
    }

    double cell_error(const RayRecord& r) const {
        const int x = std::min(int(r.px), image_.width() - 1), y = std::min(int(r.py), image_.height() - 1);
        return double(std::llabs(image_.difference(std::size_t(y) * image_.width() + x)));
    }

    // The largest cell error, refreshed at sync points only so that proposals drawn
    // between syncs do not depend on outcomes not yet known.
    void refresh_error_weights() {
        if (!proposals_.error_guided) return;
        Fixed m = 0;
        for (int k = 0; k < image_.width() * image_.height(); ++k)
            m = std::max(m, Fixed(std::llabs(image_.difference(std::size_t(k)))));
        max_error_ = double(m);
    }

    mutable Backend backend_;  // mutable: a backend may show a move to its structures in delta()
    Heightmap* surface_;
    const RaySet* rays_;
    IncrementalTrace trace_;
    ImageState image_;
    ObjectiveWeights weights_;
    const Penalties* penalties_;
    ProposalSettings proposals_;
    std::vector<Kernel> kernels_;
    AnyBandit bandit_;
    double unit_;
    double t_ref_;
    ObjectiveValue value_;
    std::int64_t penalty_sum_ = 0;
    bool best_is_current_ = true;
    std::vector<float> best_heights_;
    double max_error_ = 0;
    std::int64_t recentres_ = 0;
    int row0_ = 0, row1_;  // centre rows [row0_, row1_): the whole mesh unless set_centre_rows
    mutable std::unique_ptr<WindowEvaluator> evaluator_;  // delta_window's, null: windows off
    mutable std::string window_failure_;                  // why it was dropped (drop_evaluator)
    mutable std::vector<HeightOverlay> window_moves_;  // its moves that change something
};

using SurfaceProblem = BasicSurfaceProblem<HeightfieldBackend>;

}  // namespace freeform
