#pragma once
// The names of an enumeration's values: one table per enum, defined next to the enum
// (core/deposit.hpp, core/material.hpp, surface/heightmap.hpp, scene/light.hpp,
// scene/scene.hpp). The scene reader (io/scene_json.hpp), the command line and the reports
// look names up in it and print its list in their messages, so a name is spelt once.
#include <array>
#include <cstddef>
#include <optional>
#include <string>
#include <string_view>

namespace freeform {

template <class E>
struct EnumName {
    std::string_view name;
    E value;
};

// The value named `name`; nullopt when the table has no such name.
template <class E, std::size_t N>
constexpr std::optional<E> enum_value(std::string_view name, const std::array<EnumName<E>, N>& names) {
    for (const auto& n : names)
        if (n.name == name) return n.value;
    return std::nullopt;
}

// The name of `value` (the table's first name for a value it does not list).
template <class E, std::size_t N>
constexpr std::string_view enum_name(E value, const std::array<EnumName<E>, N>& names) {
    for (const auto& n : names)
        if (n.value == value) return n.name;
    return names[0].name;
}

// The names for a message: each in `quote`, separated by ", " and by `last` before the
// last one (`"a", "b", "c"`; a, b or c).
template <class E, std::size_t N>
std::string enum_list(const std::array<EnumName<E>, N>& names, std::string_view quote = "",
                      std::string_view last = ", ") {
    std::string list;
    for (std::size_t k = 0; k < N; ++k) {
        if (k > 0) list += k + 1 == N ? last : std::string_view(", ");
        list.append(quote).append(names[k].name).append(quote);
    }
    return list;
}

}  // namespace freeform
