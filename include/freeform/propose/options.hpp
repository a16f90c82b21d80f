#pragma once
// The proposal module's options: how moves are made (the kernel shapes, the bandit that
// picks among them, how far a move may shift light). The scene file's "optimise" block
// sets them (io/scene_json.hpp; docs/scene.md lists each key); design/options.hpp
// composes them with the other modules' options into DesignOptions.
#include <array>
#include <cstdint>
#include <string_view>

#include "../core/enum_names.hpp"

namespace freeform {

// The kernels moves are made of: the bank of shapes a bandit chooses from, or one round
// kernel (the reference's single-kernel baseline).
enum class KernelShapes { bank, isotropic };
// The bandit that picks a kernel shape (propose/bandit.hpp), in order of sophistication.
enum class BanditKind { uniform, history, ucb1, discounted_ucb };

// Their names in scene files and reports: the one mapping between the strings and the
// values (io/scene_json.hpp reads and writes with it).
inline constexpr std::array<EnumName<KernelShapes>, 2> kernel_shape_names{
    {{"bank", KernelShapes::bank}, {"isotropic", KernelShapes::isotropic}}};
inline constexpr std::array<EnumName<BanditKind>, 4> bandit_kind_names{{{"uniform", BanditKind::uniform},
                                                                        {"history", BanditKind::history},
                                                                        {"ucb1", BanditKind::ucb1},
                                                                        {"discounted-ucb", BanditKind::discounted_ucb}}};
inline std::string_view to_string(KernelShapes k) { return enum_name(k, kernel_shape_names); }
inline std::string_view to_string(BanditKind b) { return enum_name(b, bandit_kind_names); }

struct ProposalOptions {
    KernelShapes kernel_shapes = KernelShapes::bank;
    BanditKind bandit = BanditKind::history;
    int bandit_sync = 64;                       // proposals between the bandit's updates
    std::int64_t preprocess_iterations = 1000;  // history bandit: trial run with all shapes (0: none)
    int preprocess_keep = 4;                    // ... after which the best shapes are kept
    bool error_guided = false;                  // centre moves where the error is (propose/kernel.hpp)
    bool single_vertex = false;                 // one vertex per move instead of a kernel
    double max_shift_cells = 4.0;               // largest light shift of a move, in receiver cells
    double min_shift_cells = 0.25;              // ... smallest
    double refine_max_shift_cells = 1.0;        // largest light shift after a transport start
};

}  // namespace freeform
