#pragma once
// How the receiver records a ray's weight (docs/scene.md, receiver.deposit; docs/measures.md).
#include <array>
#include <cstdint>

#include "enum_names.hpp"

namespace freeform {

enum class Deposit : std::uint8_t {
    nearest,        // all of a ray's weight goes to the cell it hits: cell means, what a camera records
    bilinear,       // split among the four nearest cell centres: the irradiance seen through a tent two
                    // cells wide, blind to a pattern that alternates from cell to cell
    fine_bilinear,  // bilinear on a grid k times finer, summed into cells: all in the cell hit
                    // unless within 1/(2k) of a cell of an edge, where it ramps linearly into the
                    // neighbour (half at the edge). Continuous in the landing point like bilinear,
                    // and it sees every scale the receiver resolves (the default)
};

// fine_bilinear's k: 5 (a ramp a tenth of a cell either side of an edge), or 2 (a quarter
// cell) where the light source's own extent blurs an image point over a cell or more
// (trace/setup.hpp, fine_deposit_factor_for). Until 2026-11-30 k was 2 everywhere: with
// the wide ramp the annealer placed light near edges, where the deposit counts it on both
// sides and a camera on one; where the source blurs the image the surface cannot place
// light that finely, and the wider ramp only averages the rays' noise (docs/measures.md,
// "The deposit's ramp").
inline constexpr int fine_deposit_factor = 5;
inline constexpr int fine_deposit_factor_blurred = 2;

// Their names in scene files (receiver.deposit).
inline constexpr std::array<EnumName<Deposit>, 3> deposit_names{
    {{"fine_bilinear", Deposit::fine_bilinear}, {"bilinear", Deposit::bilinear}, {"nearest", Deposit::nearest}}};

}  // namespace freeform
