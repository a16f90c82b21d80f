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
    fine_bilinear,  // bilinear on a grid twice as fine, summed into cells: all in the cell hit unless
                    // within a quarter cell of an edge, where it ramps linearly into the neighbour
                    // (half at the edge). Continuous in the landing point like bilinear, and it sees
                    // every scale the receiver resolves (the default)
};

// Their names in scene files (receiver.deposit).
inline constexpr std::array<EnumName<Deposit>, 3> deposit_names{
    {{"fine_bilinear", Deposit::fine_bilinear}, {"bilinear", Deposit::bilinear}, {"nearest", Deposit::nearest}}};

}  // namespace freeform
