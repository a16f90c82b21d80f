#pragma once
// The designed surface as a grid sag table (surface.dat): the text format of OpticStudio's
// Grid Sag surface, which optical design programs load as a freeform surface
// (docs/export.md).
//
// Layout, as OpticStudio documents it:
//   line 1:  nx ny delx dely unitflag xdec ydec
//            (points per direction, spacing, unit 0 = mm / 1 = cm / 2 = in / 3 = m,
//            decentre of the grid)
//   then nx·ny lines: z dz/dx dz/dy d²z/dxdy nodata
// z and d²z/dxdy carry the unit (mm and 1/mm here), the slopes are dimensionless, and
// nodata is 0 for a valid point. The first point is the upper left corner of the grid
// (x = −(nx−1)·delx/2, y = +(ny−1)·dely/2), the points run along +x, and the rows from
// the top (+y) down. Between points the program interpolates bicubically from the four
// numbers at each corner.
//
// We write the design itself at its grid vertices, not the B-spline of the STEP part:
// z is the height map's vertex height, dz/dx and dz/dy the slopes of its own vertex
// normals (Heightmap::normals(), the normals the Phong patches are built from; slope =
// −n_x/n_z, −n_y/n_z), so the program's bicubic interpolation is a C¹
// Hermite surface through the designed vertices with the designed normals there. Between
// the vertices it departs from the Phong patches the design simulated by what a cubic
// makes of the same corner data (docs/export.md gives the figures). x, y, z are the
// surface frame's u, v, w in millimetres (w towards the light); the grid is centred on the
// frame's origin (decentres 0). Cells outside an elliptical aperture are written too: the
// sag covers the rectangle.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "../core/error.hpp"
#include "../surface/bspline.hpp"  // SplineSample (what eval returns), hermite_corners
#include "../surface/heightmap.hpp"
#include "file.hpp"
#include "mesh.hpp"

namespace freeform::io {

// A grid sag table as read back (lengths in metres, slopes dimensionless).
struct GridSag {
    int nx = 0, ny = 0;
    double dx = 0, dy = 0;      // spacing
    double x_dec = 0, y_dec = 0;
    // Per point, row-major from the LOWER left corner (index j·nx + i, x = x0 + i·dx,
    // y = y0 + j·dy): the file's rows reversed, so that j grows with y.
    std::vector<double> z, z_x, z_y, z_xy;

    double x0() const { return x_dec - 0.5 * (nx - 1) * dx; }
    double y0() const { return y_dec - 0.5 * (ny - 1) * dy; }

    // The bicubic Hermite interpolation of the table at (x, y), clamped to the grid: the
    // surface an optical design program builds from it. Returns z and its slopes.
    SplineSample eval(double x, double y) const {
        const double fx = std::clamp((x - x0()) / dx, 0.0, double(nx - 1));
        const double fy = std::clamp((y - y0()) / dy, 0.0, double(ny - 1));
        const int i = std::min(int(fx), nx - 2), j = std::min(int(fy), ny - 2);
        const double s = fx - i, t = fy - j;
        // Cubic Hermite basis (values h, slopes per unit parameter g) and their derivatives.
        const auto hermite = [](double a, double (&h)[2], double (&g)[2], double (&dh)[2], double (&dg)[2]) {
            h[0] = 1 - 3 * a * a + 2 * a * a * a, h[1] = 3 * a * a - 2 * a * a * a;
            g[0] = a - 2 * a * a + a * a * a, g[1] = -a * a + a * a * a;
            dh[0] = -6 * a + 6 * a * a, dh[1] = 6 * a - 6 * a * a;
            dg[0] = 1 - 4 * a + 3 * a * a, dg[1] = -2 * a + 3 * a * a;
        };
        double hs[2], gs[2], dhs[2], dgs[2], ht[2], gt[2], dht[2], dgt[2];
        hermite(s, hs, gs, dhs, dgs);
        hermite(t, ht, gt, dht, dgt);
        SplineSample out;
        for (int b = 0; b < 2; ++b)
            for (int a = 0; a < 2; ++a) {
                const std::size_t k = std::size_t(j + b) * std::size_t(nx) + std::size_t(i + a);
                // Corner data in parameter units: slopes times the spacing.
                const double f = z[k], fs = z_x[k] * dx, ft = z_y[k] * dy, fst = z_xy[k] * dx * dy;
                const auto term = [&](const double* us, const double* vs) {
                    return us[0] * vs[0] * f + us[1] * vs[0] * fs + us[0] * vs[1] * ft + us[1] * vs[1] * fst;
                };
                const double u0[2] = {hs[a], gs[a]}, v0[2] = {ht[b], gt[b]};
                const double u1[2] = {dhs[a], dgs[a]}, v1[2] = {dht[b], dgt[b]};
                out.z += term(u0, v0);
                out.z_u += term(u1, v0) / dx;
                out.z_v += term(u0, v1) / dy;
                out.z_uv += term(u1, v1) / (dx * dy);
            }
        return out;
    }
};

// The grid sag table of the height map `hm` (metres, j growing with v): per vertex its
// height, the slopes of its vertex normal, and the twist d²z/dudv (hermite_corners,
// surface/bspline.hpp, which says how the twist is taken).
inline GridSag grid_sag_of(const Heightmap& hm) {
    if (hm.nx() < 2 || hm.ny() < 2) throw InputError("grid sag: the height map has fewer than 2 x 2 vertices");
    HermiteCorners c = hermite_corners(hm);
    GridSag g;
    g.nx = hm.nx(), g.ny = hm.ny(), g.dx = hm.du(), g.dy = hm.dv();
    g.z = std::move(c.z), g.z_x = std::move(c.z_u), g.z_y = std::move(c.z_v), g.z_xy = std::move(c.z_uv);
    return g;
}

// Writes `g` as an OpticStudio grid sag table (millimetres, rows from the top down).
// Throws IoError naming the file when it cannot be written.
inline void write_grid_sag(const std::filesystem::path& file, const GridSag& g) {
    const double mm = 1000.0;
    std::string text;
    text.reserve(std::size_t(g.nx) * std::size_t(g.ny) * 80 + 100);
    char line[200];
    std::snprintf(line, sizeof line, "%d %d %.17g %.17g 0 %.17g %.17g\n", g.nx, g.ny, g.dx * mm, g.dy * mm,
                  g.x_dec * mm, g.y_dec * mm);
    text += line;
    for (int j = g.ny - 1; j >= 0; --j)  // the file starts at the top row (+y)
        for (int i = 0; i < g.nx; ++i) {
            const std::size_t k = std::size_t(j) * std::size_t(g.nx) + std::size_t(i);
            std::snprintf(line, sizeof line, "%.12e %.12e %.12e %.12e 0\n", g.z[k] * mm, g.z_x[k], g.z_y[k],
                          g.z_xy[k] / mm);
            text += line;
        }
    write_file_atomically(file, text);
}

// Writes the height map `hm` as a grid sag table (grid_sag_of): the design at its vertices.
inline void write_grid_sag(const std::filesystem::path& file, const Heightmap& hm) {
    write_grid_sag(file, grid_sag_of(hm));
}

// Reads a grid sag table (any unit flag; lengths converted to metres). Throws IoError for
// a missing file, and InputError naming the line for a malformed one.
inline GridSag read_grid_sag(const std::filesystem::path& file) {
    const std::string bytes = read_file_bytes(file);
    GridSag g;
    const std::string where = "grid sag '" + file.string() + "'";
    std::vector<std::string_view> header;
    double unit = 1e-3;
    std::size_t point = 0;
    detail::for_each_line(bytes, [&](int number, std::string_view line) {
        const auto tokens = detail::split_whitespace(line);
        if (tokens.empty() || tokens.front().front() == '!') return;  // blank or comment
        const auto bad = [&](const std::string& why) {
            throw InputError(where + ", line " + std::to_string(number) + ": " + why);
        };
        if (g.nx == 0) {
            long long nx = 0, ny = 0, flag = 0;
            double v[4];
            if (tokens.size() < 5 || !detail::parse_int(tokens[0], nx) || !detail::parse_int(tokens[1], ny) ||
                !detail::parse_double(tokens[2], v[0]) || !detail::parse_double(tokens[3], v[1]) ||
                !detail::parse_int(tokens[4], flag))
                bad("expected 'nx ny delx dely unitflag xdec ydec'");
            if (nx < 2 || ny < 2 || nx > 100000 || ny > 100000 || nx * ny > 200000000LL)
                bad("grid of " + std::to_string(nx) + " x " + std::to_string(ny) + " points");
            static constexpr double units[4] = {1e-3, 1e-2, 0.0254, 1.0};
            if (flag < 0 || flag > 3) bad("unit flag must be 0, 1, 2 or 3, got " + std::to_string(flag));
            unit = units[flag];
            v[2] = v[3] = 0;
            for (std::size_t k = 5; k < 7 && k < tokens.size(); ++k)
                if (!detail::parse_double(tokens[k], v[k - 3])) bad("decentre is not a number");
            if (!(v[0] != 0) || !(v[1] != 0)) bad("delx and dely must not be zero");
            g.nx = int(nx), g.ny = int(ny);
            g.dx = std::abs(v[0]) * unit, g.dy = std::abs(v[1]) * unit;
            g.x_dec = v[2] * unit, g.y_dec = v[3] * unit;
            const std::size_t n = std::size_t(nx) * std::size_t(ny);
            g.z.assign(n, 0), g.z_x.assign(n, 0), g.z_y.assign(n, 0), g.z_xy.assign(n, 0);
            return;
        }
        if (point >= g.z.size()) bad("more than nx*ny points");
        double v[4] = {0, 0, 0, 0};
        if (tokens.empty() || tokens.size() > 5) bad("expected 'z dz/dx dz/dy d2z/dxdy nodata'");
        for (std::size_t k = 0; k < tokens.size() && k < 4; ++k)
            if (!detail::parse_double(tokens[k], v[k])) bad("not a number: '" + std::string(tokens[k]) + "'");
        const std::size_t row = point / std::size_t(g.nx), col = point % std::size_t(g.nx);
        const std::size_t k = (std::size_t(g.ny) - 1 - row) * std::size_t(g.nx) + col;
        g.z[k] = v[0] * unit, g.z_x[k] = v[1], g.z_y[k] = v[2], g.z_xy[k] = v[3] / unit;
        ++point;
    });
    if (g.nx == 0) throw InputError(where + ": no header line");
    if (point != g.z.size())
        throw InputError(where + ": " + std::to_string(point) + " points for a " + std::to_string(g.nx) + " x " +
                         std::to_string(g.ny) + " grid");
    return g;
}

}  // namespace freeform::io
