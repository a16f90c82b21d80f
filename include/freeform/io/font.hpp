#pragma once
// Text targets: locate a TrueType font and rasterise a string (stb_truetype, linked
// from libstb) into a grey image, as large as fits, so that "target": {"text": "E"}
// needs no image file.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <limits>
#include <string>
#include <string_view>
#include <system_error>
#include <vector>

#include <stb_truetype.h>

#include "../core/error.hpp"
#include "../core/histogram.hpp"
#include "file.hpp"

namespace freeform::io {

namespace detail {

inline std::vector<std::filesystem::path> font_directories() {
    std::vector<std::filesystem::path> dirs = {"/usr/share/fonts/truetype/dejavu", "/usr/share/fonts",
                                               "/usr/local/share/fonts"};
    if (const char* home = std::getenv("HOME"); home && *home) {
        dirs.emplace_back(std::filesystem::path(home) / ".local/share/fonts");
        dirs.emplace_back(std::filesystem::path(home) / ".fonts");
    }
    return dirs;
}

// Decodes UTF-8 into code points; throws InputError at the first invalid sequence.
inline std::vector<char32_t> decode_utf8(const std::string& text) {
    std::vector<char32_t> out;
    for (std::size_t i = 0; i < text.size();) {
        const auto lead = static_cast<unsigned char>(text[i]);
        int extra = 0;
        char32_t cp = 0;
        if (lead < 0x80) {
            cp = lead;
        } else if ((lead & 0xE0) == 0xC0) {
            extra = 1;
            cp = lead & 0x1F;
        } else if ((lead & 0xF0) == 0xE0) {
            extra = 2;
            cp = lead & 0x0F;
        } else if ((lead & 0xF8) == 0xF0) {
            extra = 3;
            cp = lead & 0x07;
        } else {
            throw InputError("render_text: invalid UTF-8 byte at offset " + std::to_string(i) + " of the text");
        }
        if (i + std::size_t(extra) >= text.size() && extra > 0)
            throw InputError("render_text: truncated UTF-8 sequence at offset " + std::to_string(i) + " of the text");
        for (int k = 1; k <= extra; ++k) {
            const auto next = static_cast<unsigned char>(text[i + std::size_t(k)]);
            if ((next & 0xC0) != 0x80)
                throw InputError("render_text: invalid UTF-8 sequence at offset " + std::to_string(i) + " of the text");
            cp = (cp << 6) | (next & 0x3F);
        }
        static constexpr char32_t smallest[4] = {0, 0x80, 0x800, 0x10000};
        if (cp < smallest[extra] || cp > 0x10FFFF || (cp >= 0xD800 && cp <= 0xDFFF))
            throw InputError("render_text: invalid UTF-8 sequence at offset " + std::to_string(i) + " of the text");
        out.push_back(cp);
        i += std::size_t(extra) + 1;
    }
    return out;
}

inline std::string codepoint_name(char32_t cp) {
    char name[16];
    std::snprintf(name, sizeof name, "U+%04X", unsigned(cp));
    return name;
}

}  // namespace detail

// Finds a font file: `name` may be an existing path, a file name ("DejaVuSans-Bold.ttf")
// or a bare name ("DejaVuSans-Bold", tried with .ttf, .otf and .ttc). Looks in
// /usr/share/fonts/truetype/dejavu, then recursively in /usr/share/fonts,
// /usr/local/share/fonts, ~/.local/share/fonts and ~/.fonts. Throws IoError listing
// where it looked.
inline std::filesystem::path find_font(const std::string& name) {
    namespace fs = std::filesystem;
    if (name.empty()) throw IoError("find_font: empty font name");
    std::error_code ec;
    if (fs::is_regular_file(name, ec)) return name;

    std::vector<std::string> file_names;
    const fs::path as_path(name);
    if (as_path.has_extension())
        file_names.push_back(as_path.filename().string());
    for (const char* ext : {".ttf", ".otf", ".ttc"}) file_names.push_back(as_path.filename().string() + ext);

    const auto dirs = detail::font_directories();
    for (const fs::path& dir : dirs) {
        for (const std::string& file_name : file_names)
            if (fs::is_regular_file(dir / file_name, ec)) return dir / file_name;
        // Font packages sort files into sub-directories; the lexicographically first
        // match keeps the choice independent of directory iteration order.
        fs::path best;
        for (fs::recursive_directory_iterator it(dir, fs::directory_options::skip_permission_denied, ec), end;
             !ec && it != end; it.increment(ec)) {
            const fs::path& candidate = it->path();
            if (std::find(file_names.begin(), file_names.end(), candidate.filename().string()) != file_names.end() &&
                it->is_regular_file(ec) && (best.empty() || candidate < best))
                best = candidate;
        }
        if (!best.empty()) return best;
        ec.clear();
    }

    std::string looked;
    for (const fs::path& dir : dirs) looked += (looked.empty() ? "" : ", ") + dir.string();
    throw IoError("font '" + name + "' not found: not an existing file, and no " + file_names.front() +
                  (file_names.size() > 1 ? " (or .otf/.ttc)" : "") + " in " + looked);
}

namespace detail {

inline std::uint64_t font_u16(std::string_view b, std::uint64_t at) {
    return (std::uint64_t(static_cast<unsigned char>(b[at])) << 8) | static_cast<unsigned char>(b[at + 1]);
}
inline std::uint64_t font_u32(std::string_view b, std::uint64_t at) {
    return (font_u16(b, at) << 16) | font_u16(b, at + 2);
}

// stb_truetype trusts the offsets in a font file. Before it sees one, the table
// directory of the first font (of a collection, too) must lie inside the file and every
// table it lists must end inside the file; a truncated or foreign file fails here.
// (The glyph outlines themselves are not checked: font files are taken to come from a
// font package or the user, not from an untrusted source; docs/limits.md.)
inline bool font_directory_fits(std::string_view b) {
    if (b.size() < 12) return false;
    std::uint64_t font = 0;
    if (b.substr(0, 4) == "ttcf") {
        if (b.size() < 16) return false;
        font = font_u32(b, 12);
    }
    if (font + 12 > b.size()) return false;
    const std::uint64_t tables = font_u16(b, font + 4);
    if (font + 12 + 16 * tables > b.size()) return false;
    for (std::uint64_t t = 0; t < tables; ++t) {
        const std::uint64_t record = font + 12 + 16 * t;
        if (font_u32(b, record + 8) + font_u32(b, record + 12) > b.size()) return false;
    }
    return true;
}

// A glyph laid out in font units with y pointing down (image convention).
struct PlacedGlyph {
    int glyph;
    double pen_x, baseline;
};

// Lays the glyphs of `codepoints` out line by line, each line centred on x = 0 by its
// advance width. Throws IoError naming `font_file` for a codepoint the font lacks.
inline std::vector<PlacedGlyph> place_glyphs(const stbtt_fontinfo& font, const std::vector<char32_t>& codepoints,
                                             const std::filesystem::path& font_file) {
    int ascent = 0, descent = 0, line_gap = 0;
    stbtt_GetFontVMetrics(&font, &ascent, &descent, &line_gap);
    const double line_advance = double(ascent - descent + line_gap);

    std::vector<PlacedGlyph> placed;
    std::size_t line_start = 0;
    double pen = 0, baseline = 0;
    int previous = 0;
    const auto finish_line = [&] {
        // Centre the line on x = 0 by its advance width.
        for (std::size_t k = line_start; k < placed.size(); ++k) placed[k].pen_x -= pen / 2;
        line_start = placed.size();
    };
    for (char32_t cp : codepoints) {
        if (cp == U'\r') continue;
        if (cp == U'\n') {
            finish_line();
            pen = 0;
            previous = 0;
            baseline += line_advance;
            continue;
        }
        const int glyph = stbtt_FindGlyphIndex(&font, int(cp == U'\t' ? U' ' : cp));
        if (glyph == 0) throw IoError("font '" + font_file.string() + "' has no glyph for " + codepoint_name(cp));
        if (previous) pen += stbtt_GetGlyphKernAdvance(&font, previous, glyph);
        placed.push_back({glyph, pen, baseline});
        int advance = 0, bearing = 0;
        stbtt_GetGlyphHMetrics(&font, glyph, &advance, &bearing);
        pen += advance;
        previous = glyph;
    }
    finish_line();
    return placed;
}

// The bounding box of the glyph outlines' ink, in the layout's font units (empty, with
// x0 > x1, when no glyph has ink).
struct InkBox {
    static constexpr double inf = std::numeric_limits<double>::infinity();
    double x0 = inf, y0 = inf;
    double x1 = -inf, y1 = -inf;
};

inline InkBox ink_box(const stbtt_fontinfo& font, const std::vector<PlacedGlyph>& placed) {
    InkBox ink;
    for (const PlacedGlyph& g : placed) {
        int x0, y0, x1, y1;
        if (stbtt_IsGlyphEmpty(&font, g.glyph) || !stbtt_GetGlyphBox(&font, g.glyph, &x0, &y0, &x1, &y1)) continue;
        ink.x0 = std::min(ink.x0, g.pen_x + x0);
        ink.x1 = std::max(ink.x1, g.pen_x + x1);
        ink.y0 = std::min(ink.y0, g.baseline - y1);
        ink.y1 = std::max(ink.y1, g.baseline - y0);
    }
    return ink;
}

// Adds the antialiased coverage of the placed glyphs to `img`, font units mapped to
// pixels as scale · p + shift; the parts outside the image are dropped.
inline void draw_glyphs(const stbtt_fontinfo& font, const std::vector<PlacedGlyph>& placed, double scale,
                        double shift_x, double shift_y, ImageF& img) {
    const long long width = img.cols(), height = img.rows();
    const auto s = static_cast<float>(scale);
    std::vector<unsigned char> bitmap;
    for (const PlacedGlyph& g : placed) {
        if (stbtt_IsGlyphEmpty(&font, g.glyph)) continue;
        const double origin_x = shift_x + scale * g.pen_x, origin_y = shift_y + scale * g.baseline;
        const double base_x = std::floor(origin_x), base_y = std::floor(origin_y);
        const auto sub_x = static_cast<float>(origin_x - base_x), sub_y = static_cast<float>(origin_y - base_y);
        int ix0, iy0, ix1, iy1;
        stbtt_GetGlyphBitmapBoxSubpixel(&font, g.glyph, s, s, sub_x, sub_y, &ix0, &iy0, &ix1, &iy1);
        const int bw = ix1 - ix0, bh = iy1 - iy0;
        if (bw <= 0 || bh <= 0) continue;
        bitmap.assign(std::size_t(bw) * std::size_t(bh), 0);
        stbtt_MakeGlyphBitmapSubpixel(&font, bitmap.data(), bw, bh, bw, s, s, sub_x, sub_y, g.glyph);
        const long long left = static_cast<long long>(base_x) + ix0, top = static_cast<long long>(base_y) + iy0;
        for (int j = 0; j < bh; ++j) {
            const long long y = top + j;
            if (y < 0 || y >= height) continue;
            for (int i = 0; i < bw; ++i) {
                const long long x = left + i;
                if (x < 0 || x >= width) continue;
                // Abutting glyph edges add up; overlaps saturate.
                float& cell = img(Eigen::Index(y), Eigen::Index(x));
                cell = std::min(1.0f, cell + bitmap[std::size_t(j) * bw + i] / 255.0f);
            }
        }
    }
}

}  // namespace detail

// Renders UTF-8 `text` ('\n' separates lines, each centred) as white antialiased
// coverage in [0, 1] on black, in a height × width image. The ink bounding box (from
// the glyph outlines) is scaled as large as fits inside the image minus `margin` (a
// fraction of the width and of the height on each side, in [0, 0.5)) and centred.
// Throws IoError if the font cannot be loaded, lacks a glyph, or the text has no ink;
// InputError for bad sizes or invalid UTF-8.
inline ImageF render_text(const std::string& text, const std::filesystem::path& font_file, int width, int height,
                          double margin) {
    if (width <= 0 || height <= 0)
        throw InputError("render_text: image size " + std::to_string(width) + " x " + std::to_string(height) +
                         " must be positive");
    if (!(margin >= 0 && margin < 0.5))
        throw InputError("render_text: margin " + std::to_string(margin) + " must be in [0, 0.5)");
    const std::vector<char32_t> codepoints = detail::decode_utf8(text);

    const std::string font_bytes = read_file_bytes(font_file);
    const auto* font_data = reinterpret_cast<const unsigned char*>(font_bytes.data());
    stbtt_fontinfo font{};
    const int offset = detail::font_directory_fits(font_bytes) ? stbtt_GetFontOffsetForIndex(font_data, 0) : -1;
    if (offset < 0 || !stbtt_InitFont(&font, font_data, offset))
        throw IoError("cannot load font '" + font_file.string() + "': not a TrueType/OpenType font");

    const std::vector<detail::PlacedGlyph> placed = detail::place_glyphs(font, codepoints, font_file);
    const detail::InkBox ink = detail::ink_box(font, placed);
    if (!(ink.x1 > ink.x0) || !(ink.y1 > ink.y0))
        throw IoError("text '" + text + "' renders no ink with font '" + font_file.string() + "'");

    // The slight shrink keeps rounding from pushing antialiased edges into the margin.
    const double fit_w = width * (1 - 2 * margin), fit_h = height * (1 - 2 * margin);
    const double scale = std::min(fit_w / (ink.x1 - ink.x0), fit_h / (ink.y1 - ink.y0)) * (1 - 1e-6);
    const double shift_x = width / 2.0 - scale * (ink.x0 + ink.x1) / 2;
    const double shift_y = height / 2.0 - scale * (ink.y0 + ink.y1) / 2;

    ImageF img = ImageF::Zero(height, width);
    detail::draw_glyphs(font, placed, scale, shift_x, shift_y, img);
    if (!(img.maxCoeff() > 0))
        throw IoError("text '" + text + "' renders no ink with font '" + font_file.string() + "' at " +
                      std::to_string(width) + " x " + std::to_string(height));
    return img;
}

}  // namespace freeform::io
