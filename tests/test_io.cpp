// The io module: PFM/PNG/OBJ/STL round trips checked against raw file bytes, error
// messages that name the file (and line), and text rendering geometry.
#include <doctest/doctest.h>

#include <freeform/io.hpp>
#include <freeform/io/outputs.hpp>

#include <algorithm>
#include <bit>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include <stb_image_write.h>

#include "files.hpp"

namespace fs = std::filesystem;
using freeform::ImageD;
using freeform::ImageF;
using freeform::InputError;
using freeform::Scene;
using freeform::TargetSpec;
using freeform::TargetFit;
using freeform::TargetUpsample;
using freeform::IoError;
using freeform::TriangleMesh;
using freeform::Vec3d;
namespace io = freeform::io;

namespace {

using freeform::testing::read_raw;
using freeform::testing::write_raw;

struct TempDir : freeform::testing::TempDir {
    TempDir() : freeform::testing::TempDir("freeform_test_io_") {}
};

std::string float_bytes(float v, bool little_endian) {
    std::uint32_t bits = std::bit_cast<std::uint32_t>(v);
    std::string out(4, '\0');
    for (int k = 0; k < 4; ++k) {
        const int shift = little_endian ? 8 * k : 8 * (3 - k);
        out[std::size_t(k)] = static_cast<char>((bits >> shift) & 0xffu);
    }
    return out;
}

float float_at(const std::string& bytes, std::size_t offset) {
    std::uint32_t bits = 0;
    for (int k = 0; k < 4; ++k) bits |= std::uint32_t(static_cast<unsigned char>(bytes[offset + std::size_t(k)])) << (8 * k);
    return std::bit_cast<float>(bits);
}

// The message of the IoError thrown by f, or "" (and a failed check) if none is thrown.
template <class F>
std::string io_error_message(F&& f) {
    try {
        f();
    } catch (const IoError& e) {
        return e.what();
    } catch (...) {
        FAIL("threw something other than IoError");
        return "";
    }
    FAIL("did not throw");
    return "";
}

bool contains(const std::string& haystack, const std::string& needle) {
    return haystack.find(needle) != std::string::npos;
}

bool has_temp_leftovers(const fs::path& dir) {
    for (const auto& entry : fs::directory_iterator(dir))
        if (contains(entry.path().filename().string(), ".tmp")) return true;
    return false;
}

ImageF test_pattern(int height, int width) {
    ImageF img(height, width);
    for (int y = 0; y < height; ++y)
        for (int x = 0; x < width; ++x) img(y, x) = std::sin(0.37f * float(x) + 1.3f * float(y)) * 1e3f + float(y);
    return img;
}

}  // namespace

TEST_CASE("PFM round trip is bit exact and stores the bottom row first") {
    TempDir dir;
    ImageF img = test_pattern(5, 7);
    img(0, 0) = 42.0f;                                  // top-left
    img(4, 0) = -7.25f;                                 // bottom-left
    img(2, 3) = std::numeric_limits<float>::denorm_min();
    img(1, 1) = -0.0f;
    const fs::path file = dir / "pattern.pfm";
    io::write_pfm(file, img);

    const ImageF back = io::read_pfm(file);
    REQUIRE(back.rows() == 5);
    REQUIRE(back.cols() == 7);
    for (int y = 0; y < 5; ++y)
        for (int x = 0; x < 7; ++x)
            CHECK(std::bit_cast<std::uint32_t>(back(y, x)) == std::bit_cast<std::uint32_t>(img(y, x)));

    const std::string raw = read_raw(file);
    const std::string header = "Pf\n7 5\n-1.0\n";
    REQUIRE(raw.size() == header.size() + 5 * 7 * 4);
    CHECK(raw.substr(0, header.size()) == header);
    CHECK(float_at(raw, header.size()) == -7.25f);                   // first stored row = bottom row
    CHECK(float_at(raw, header.size() + 4 * 7 * 4) == 42.0f);        // last stored row = top row
    CHECK(float_at(raw, header.size() + (0 * 7 + 3) * 4) == img(4, 3));
    CHECK_FALSE(has_temp_leftovers(dir.path));
}

TEST_CASE("load_target_image brings a coarse image up to the receiver smoothly, or as blocks on request") {
    TempDir dir;
    ImageF img(2, 3);  // 3 x 2 pixels: a left-to-right ramp on top, dark below
    img << 1.0f, 2.0f, 3.0f,  //
        0.0f, 0.0f, 0.0f;
    const fs::path file = dir / "coarse.pfm";
    io::write_pfm(file, img);
    Scene scene;
    scene.receiver.width = 12;
    scene.receiver.height = 2;
    scene.target = TargetSpec{};
    scene.target->image = file;
    const ImageD smooth = io::load_target_image(scene);
    REQUIRE(smooth.cols() == 12);  // columns brought up to the receiver's 12
    REQUIRE(smooth.rows() == 2);   // rows already enough: kept
    for (int x = 1; x < 12; ++x) CHECK(smooth(0, x) >= smooth(0, x - 1));
    CHECK(smooth(0, 0) == doctest::Approx(1.0));    // before the first centre: the first pixel
    CHECK(smooth(0, 5) == doctest::Approx(1.875));  // [1.25, 1.5]: the line t + ½ has mean 1.875 there
    CHECK(smooth(1, 7) == 0.0);
    scene.target->upsample = TargetUpsample::box;
    const ImageD blocks = io::load_target_image(scene);
    REQUIRE(blocks.cols() == 3);  // as stored: make_target area-averages it (blocks of 4)
    CHECK(blocks(0, 1) == 2.0);
}

TEST_CASE("target.fit: a disc on a 4:3 picture stays round on a square receiver with contain and cover") {
    // The picture: a bright disc of radius 5 pixels in the middle of a 40 x 30 canvas.
    TempDir dir;
    ImageF img(30, 40);
    for (int y = 0; y < 30; ++y)
        for (int x = 0; x < 40; ++x) img(y, x) = std::hypot(x + 0.5 - 20.0, y + 0.5 - 15.0) < 5.0 ? 1.0f : 0.0f;
    const fs::path file = dir / "disc.pfm";
    io::write_pfm(file, img);
    Scene scene;
    scene.receiver.width = scene.receiver.height = 60;  // 0.2 x 0.2 m
    scene.target = TargetSpec{};
    scene.target->image = file;
    // The spread of the light along each receiver axis, in metres: its second moment about
    // its centroid, from the fixed-point target a level is fitted to.
    auto spreads = [&](const ImageD& image) {
        const freeform::Target t = freeform::make_target(image, 60, 60, freeform::Fixed(1) << 40);
        double m = 0, mx = 0, my = 0, mxx = 0, myy = 0;
        for (int y = 0; y < 60; ++y)
            for (int x = 0; x < 60; ++x) {
                const double w = double(t.cells[std::size_t(y * 60 + x)]);
                const double px = (x + 0.5) / 60 * 0.2, py = (y + 0.5) / 60 * 0.2;
                m += w, mx += w * px, my += w * py, mxx += w * px * px, myy += w * py * py;
            }
        mx /= m, my /= m;
        CHECK(mx == doctest::Approx(0.1).epsilon(1e-9));  // centred
        CHECK(my == doctest::Approx(0.1).epsilon(1e-9));
        return std::pair{std::sqrt(mxx / m - mx * mx), std::sqrt(myy / m - my * my)};
    };
    const io::LoadedTarget stretched = io::load_target(scene);
    CHECK(stretched.picture_width == 40);
    CHECK(stretched.picture_height == 30);
    CHECK(stretched.stretch == doctest::Approx(4.0 / 3.0));
    const auto [sx, sy] = spreads(stretched.image);
    CHECK(sy / sx == doctest::Approx(4.0 / 3.0).epsilon(0.03));  // an upright ellipse
    scene.target->fit = TargetFit::contain;
    const io::LoadedTarget contained = io::load_target(scene);
    CHECK(contained.stretch == 1.0);
    const auto [cx, cy] = spreads(contained.image);
    CHECK(cy / cx == doctest::Approx(1.0).epsilon(0.01));  // round again
    // The disc, 10 of the picture's 40 pixels wide, spans a quarter of the receiver's width.
    CHECK(cx == doctest::Approx(sx).epsilon(0.01));
    scene.target->fit = TargetFit::cover;
    const auto [kx, ky] = spreads(io::load_target(scene).image);
    CHECK(ky / kx == doctest::Approx(1.0).epsilon(0.01));
    CHECK(kx == doctest::Approx(4.0 / 3.0 * cx).epsilon(0.01));  // a third of a picture 30 wide
    // contain past limits.pixels is refused, naming target.fit.
    scene.target->fit = TargetFit::contain;
    freeform::Limits small;
    small.pixels = 40 * 30 + 10;  // the picture fits; padded to 40 x 40, it does not
    CHECK_THROWS_WITH_AS(io::load_target(scene, small), doctest::Contains("target.fit"), InputError);
}

TEST_CASE("text keeps its shape on a receiver whose pixels are not square, and the PNGs show it so") {
    // The same text on a 0.3 x 0.2 m receiver with 300 x 200 square pixels and with 200 x 200
    // pixels 1.5 mm wide and 1 mm tall: the light's spread along each axis, in metres, is the same.
    Scene scene;
    scene.receiver.size = {0.3, 0.2};
    scene.target = TargetSpec{};
    scene.target->text = "O";
    scene.target->margin = 0.1;
    auto spreads = [&](int width, int height) {
        scene.receiver.width = width;
        scene.receiver.height = height;
        const freeform::Target t =
            freeform::make_target(io::load_target_image(scene), width, height, freeform::Fixed(1) << 40);
        double m = 0, mx = 0, my = 0, mxx = 0, myy = 0;
        for (int y = 0; y < height; ++y)
            for (int x = 0; x < width; ++x) {
                const double w = double(t.cells[std::size_t(y * width + x)]);
                const double px = (x + 0.5) * 0.3 / width, py = (y + 0.5) * 0.2 / height;
                m += w, mx += w * px, my += w * py, mxx += w * px * px, myy += w * py * py;
            }
        mx /= m, my /= m;
        return std::pair{std::sqrt(mxx / m - mx * mx), std::sqrt(myy / m - my * my)};
    };
    const auto [sx, sy] = spreads(300, 200);
    const auto [nx, ny] = spreads(200, 200);
    CHECK(nx == doctest::Approx(sx).epsilon(0.01));  // before 2026-12-01: 1.5 times as wide
    CHECK(ny == doctest::Approx(sy).epsilon(0.01));
    // The canvas: 4 text pixels a receiver pixel along the finer pitch, at most 4096 long.
    freeform::Receiver r;
    r.size = {0.3, 0.2};
    r.width = r.height = 200;
    CHECK(io::text_canvas(r) == std::pair{1200, 800});
    r.size = {0.2, 0.2};
    CHECK(io::text_canvas(r) == std::pair{800, 800});
    r.width = 2048, r.height = 1024, r.size = {0.4, 0.2};
    CHECK(io::text_canvas(r) == std::pair{4096, 2048});  // was 4096 x 4096
    // The PNGs show the 200 x 200 cells at 300 x 200, the light's mean kept; square pixels as they are.
    r.width = r.height = 200, r.size = {0.3, 0.2};
    const ImageD cells = io::load_target_image(scene);
    const ImageD shown = io::shown_square(freeform::resample_area(cells, 200, 200), r);
    CHECK(shown.cols() == 300);
    CHECK(shown.rows() == 200);
    CHECK(shown.mean() == doctest::Approx(freeform::resample_area(cells, 200, 200).mean()).epsilon(1e-9));
    r.width = 300;
    CHECK(io::shown_square(cells, r).cols() == cells.cols());
}

TEST_CASE("PFM reader: RGB averaged to grey, big-endian data, .pfm via read_image_grey") {
    TempDir dir;
    SUBCASE("RGB") {
        // 2 x 2, stored bottom row first.
        std::string bytes = "PF\n2 2\n-1.0\n";
        const float bottom[6] = {3, 6, 9, 0, 0, 3};
        const float top[6] = {1, 1, 1, -3, 0, 0};
        for (float v : bottom) bytes += float_bytes(v, true);
        for (float v : top) bytes += float_bytes(v, true);
        write_raw(dir / "rgb.pfm", bytes);
        const ImageF img = io::read_pfm(dir / "rgb.pfm");
        REQUIRE(img.rows() == 2);
        REQUIRE(img.cols() == 2);
        CHECK(img(1, 0) == doctest::Approx(6));
        CHECK(img(1, 1) == doctest::Approx(1));
        CHECK(img(0, 0) == doctest::Approx(1));
        CHECK(img(0, 1) == doctest::Approx(-1));
    }
    SUBCASE("big-endian grey, header fields on one line") {
        std::string bytes = "Pf 3 2 1.0\n";
        for (float v : {10.0f, 11.0f, 12.0f, 0.5f, -1.5f, 1e-30f}) bytes += float_bytes(v, false);
        write_raw(dir / "be.pfm", bytes);
        const ImageF img = io::read_pfm(dir / "be.pfm");
        REQUIRE(img.rows() == 2);
        REQUIRE(img.cols() == 3);
        CHECK(img(1, 0) == 10.0f);
        CHECK(img(1, 2) == 12.0f);
        CHECK(img(0, 0) == 0.5f);
        CHECK(img(0, 1) == -1.5f);
        CHECK(img(0, 2) == 1e-30f);
    }
    SUBCASE("read_image_grey dispatches on the extension") {
        const ImageF img = test_pattern(3, 4);
        io::write_pfm(dir / "h.PFM", img);
        CHECK((io::read_image_grey(dir / "h.PFM") == img).all());
    }
}

TEST_CASE("PFM reader rejects missing, corrupt and truncated files with the file name") {
    TempDir dir;
    const std::string body = float_bytes(1, true) + float_bytes(2, true);
    const std::vector<std::pair<std::string, std::string>> cases = {
        {"magic.pfm", "P6\n2 1\n-1.0\n" + body},
        {"width.pfm", "Pf\nx 1\n-1.0\n" + body},
        {"zero.pfm", "Pf\n0 1\n-1.0\n"},
        {"negative.pfm", "Pf\n2 -1\n-1.0\n" + body},
        {"huge.pfm", "Pf\n99999999 99999999\n-1.0\n" + body},
        {"scale.pfm", "Pf\n2 1\nabc\n" + body},
        {"zero_scale.pfm", "Pf\n2 1\n0\n" + body},
        {"no_scale.pfm", "Pf\n2 1"},
        {"truncated.pfm", "Pf\n2 2\n-1.0\n" + body},
        {"surplus.pfm", "Pf\n2 1\n-1.0\n" + body + "xx"},
        {"nan.pfm", "Pf\n2 1\n-1.0\n" + float_bytes(1, true) + float_bytes(std::nanf(""), true)},
        {"inf.pfm", "Pf\n2 1\n-1.0\n" + float_bytes(std::numeric_limits<float>::infinity(), true) +
                        float_bytes(1, true)},
        {"empty.pfm", ""},
    };
    for (const auto& c : cases) {
        // Variables, not a structured binding: clang < 16 cannot capture a binding in a lambda.
        const std::string& name = c.first;
        const std::string& bytes = c.second;
        CAPTURE(name);
        write_raw(dir / name, bytes);
        const std::string message = io_error_message([&] { (void)io::read_pfm(dir / name); });
        CHECK(contains(message, (dir / name).string()));
    }
    CHECK(contains(io_error_message([&] { (void)io::read_pfm(dir / "truncated.pfm"); }), "truncated"));
    CHECK(contains(io_error_message([&] { (void)io::read_pfm(dir / "nan.pfm"); }), "non-finite"));

    const std::string missing = io_error_message([&] { (void)io::read_pfm(dir / "missing.pfm"); });
    CHECK(contains(missing, (dir / "missing.pfm").string()));
    CHECK(contains(missing, "does not exist"));
}

TEST_CASE("writers create parent directories and leave nothing behind on failure") {
    TempDir dir;
    const ImageF img = test_pattern(2, 3);

    const fs::path nested = dir / "a/b/c.pfm";
    io::write_pfm(nested, img);
    CHECK((io::read_pfm(nested) == img).all());

    // Overwriting replaces the old content in one step.
    io::write_pfm(nested, img * 2);
    CHECK((io::read_pfm(nested) == img * 2).all());

    // The target is an existing directory: the rename fails after the data was written.
    fs::create_directories(dir / "occupied.pfm");
    CHECK(contains(io_error_message([&] { io::write_pfm(dir / "occupied.pfm", img); }),
                   (dir / "occupied.pfm").string()));
    CHECK_FALSE(has_temp_leftovers(dir.path));

    // The parent is a regular file.
    write_raw(dir / "plain", "x");
    CHECK(contains(io_error_message([&] { io::write_png(dir / "plain/x.png", ImageF::Zero(2, 2)); }),
                   (dir / "plain/x.png").string()));

    CHECK_THROWS_AS(io::write_pfm(dir / "empty.pfm", ImageF()), IoError);
    ImageF bad = img;
    bad(1, 2) = std::numeric_limits<float>::quiet_NaN();
    CHECK_THROWS_AS(io::write_pfm(dir / "nan.pfm", bad), IoError);
    CHECK_FALSE(fs::exists(dir / "empty.pfm"));
    CHECK_FALSE(fs::exists(dir / "nan.pfm"));
    CHECK_FALSE(has_temp_leftovers(dir.path));
}

TEST_CASE("PNG: grey round trip within 1/255, clamping, colour and alpha to luminance") {
    TempDir dir;
    ImageF img(9, 13);
    for (int y = 0; y < 9; ++y)
        for (int x = 0; x < 13; ++x) img(y, x) = float(x + 13 * y) / float(9 * 13 - 1);
    img(0, 0) = -0.5f;  // clamped to 0
    img(8, 12) = 7.0f;  // clamped to 1
    io::write_png(dir / "grey.png", img);
    const ImageF back = io::read_image_grey(dir / "grey.png");
    REQUIRE(back.rows() == 9);
    REQUIRE(back.cols() == 13);
    CHECK((back - img.max(0.0f).min(1.0f)).abs().maxCoeff() <= 0.5f / 255.0f + 1e-6f);
    CHECK(back(0, 0) == 0.0f);
    CHECK(back(8, 12) == 1.0f);

    // Pure red, green and blue pixels give their Rec. 709 weights.
    io::RgbImage rgb{3, 1, {255, 0, 0, 0, 255, 0, 0, 0, 255}};
    io::write_png(dir / "rgb.png", rgb);
    const ImageF luma = io::read_image_grey(dir / "rgb.png");
    REQUIRE(luma.cols() == 3);
    CHECK(luma(0, 0) == doctest::Approx(0.2126).epsilon(1e-4));
    CHECK(luma(0, 1) == doctest::Approx(0.7152).epsilon(1e-4));
    CHECK(luma(0, 2) == doctest::Approx(0.0722).epsilon(1e-4));

    // write_png_rgb: height rows of width * 3 interleaved bytes.
    Eigen::Array<std::uint8_t, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor> interleaved(2, 6);
    interleaved << 255, 255, 255, 0, 0, 0,  //
        0, 0, 0, 255, 255, 255;
    io::write_png_rgb(dir / "interleaved.png", interleaved, 2, 2);
    const ImageF checker = io::read_image_grey(dir / "interleaved.png");
    CHECK(checker(0, 0) == doctest::Approx(1));
    CHECK(checker(0, 1) == 0.0f);
    CHECK(checker(1, 1) == doctest::Approx(1));
    CHECK_THROWS_AS(io::write_png_rgb(dir / "bad.png", interleaved, 3, 2), InputError);

    // Alpha composites over black: a half-transparent white pixel reads as ~0.5.
    const unsigned char rgba[8] = {255, 255, 255, 128, 255, 255, 255, 0};
    REQUIRE(stbi_write_png((dir / "rgba.png").string().c_str(), 2, 1, 4, rgba, 8));
    const ImageF alpha = io::read_image_grey(dir / "rgba.png");
    CHECK(alpha(0, 0) == doctest::Approx(128.0 / 255.0).epsilon(1e-4));
    CHECK(alpha(0, 1) == 0.0f);
}

TEST_CASE("PNG reader rejects corrupt and missing files naming the file") {
    TempDir dir;
    write_raw(dir / "garbage.png", std::string("\x89PNG\r\n\x1a\n", 8) + "this is not a png at all");
    std::string message = io_error_message([&] { (void)io::read_image_grey(dir / "garbage.png"); });
    CHECK(contains(message, (dir / "garbage.png").string()));

    io::write_png(dir / "whole.png", test_pattern(40, 40) / 2000.0f + 0.5f);
    const std::string whole = read_raw(dir / "whole.png");
    write_raw(dir / "cut.png", whole.substr(0, whole.size() / 2));
    CHECK(contains(io_error_message([&] { (void)io::read_image_grey(dir / "cut.png"); }),
                   (dir / "cut.png").string()));

    write_raw(dir / "empty.jpg", "");
    CHECK(contains(io_error_message([&] { (void)io::read_image_grey(dir / "empty.jpg"); }),
                   (dir / "empty.jpg").string()));
    CHECK(contains(io_error_message([&] { (void)io::read_image_grey(dir / "nowhere.png"); }),
                   (dir / "nowhere.png").string()));
}

TEST_CASE("tone_map, diverging, grey_to_rgb and hconcat") {
    SUBCASE("tone_map maps the percentile to white and applies 1/gamma") {
        ImageD irradiance(1, 101);
        for (int x = 0; x <= 100; ++x) irradiance(0, x) = x;  // 100 positive cells 1..100
        irradiance(0, 0) = -3;                                 // negative cells stay black
        const ImageF linear = io::tone_map(irradiance, 0.5, 1.0);
        // Median of 1..100 (rank round(0.5 * 99) = 50 -> value 51).
        CHECK(linear(0, 51) == doctest::Approx(1.0));
        CHECK(linear(0, 100) == 1.0f);
        CHECK(linear(0, 0) == 0.0f);
        CHECK(linear(0, 17) == doctest::Approx(17.0 / 51.0));
        const ImageF gamma = io::tone_map(irradiance, 0.5, 2.0);
        CHECK(gamma(0, 17) == doctest::Approx(std::sqrt(17.0 / 51.0)));
        CHECK((io::tone_map(ImageD::Zero(3, 4)) == 0.0f).all());
        CHECK_THROWS_AS(io::tone_map(irradiance, 0.0), InputError);
        CHECK_THROWS_AS(io::tone_map(irradiance, 0.9, -1.0), InputError);
    }
    SUBCASE("diverging: white at zero, red positive, blue negative, saturating at the limit") {
        ImageD values(1, 5);
        values << 0, 2, -2, 1, 50;
        const io::RgbImage img = io::diverging(values, 2.0);
        REQUIRE(img.rgb.size() == 15);
        auto px = [&](int x) { return std::vector<int>(img.rgb.begin() + 3 * x, img.rgb.begin() + 3 * x + 3); };
        CHECK(px(0) == std::vector<int>{255, 255, 255});
        CHECK(px(1)[0] > px(1)[2]);  // red dominates
        CHECK(px(2)[2] > px(2)[0]);  // blue dominates
        CHECK(px(4) == px(1));       // beyond the limit saturates
        for (int c = 0; c < 3; ++c) CHECK(px(3)[std::size_t(c)] == (255 + px(1)[std::size_t(c)] + 1) / 2);
        CHECK(io::diverging(values, 0.0).rgb == io::diverging(values.sign(), 1.0).rgb);
        CHECK_THROWS_AS(io::diverging(values, -1.0), InputError);
    }
    SUBCASE("hconcat pads shorter parts with black") {
        ImageF a = ImageF::Constant(3, 2, 1.0f);
        ImageF b = ImageF::Constant(1, 1, 0.5f);
        const io::RgbImage joined = io::hconcat({io::grey_to_rgb(a), io::grey_to_rgb(b)}, 1);
        CHECK(joined.width == 4);
        CHECK(joined.height == 3);
        REQUIRE(joined.rgb.size() == 4 * 3 * 3);
        auto at = [&](int x, int y) { return int(joined.rgb[std::size_t(3 * (y * 4 + x))]); };
        CHECK(at(0, 0) == 255);
        CHECK(at(1, 2) == 255);
        CHECK(at(2, 0) == 0);    // gap
        CHECK(at(3, 0) == 128);  // 0.5 -> 128
        CHECK(at(3, 1) == 0);    // padding
        CHECK_THROWS_AS(io::hconcat({io::RgbImage{2, 2, {1, 2, 3}}}), InputError);
    }
}

TEST_CASE("OBJ: write/read round trip with and without normals") {
    TempDir dir;
    TriangleMesh mesh;
    mesh.vertices = {{0, 0, 0}, {1.25, 0, 1e-7}, {0.1, 0.2, 0.3}, {-3.5, 1e5, 0.123456789}};
    mesh.triangles = {{{0, 1, 2}}, {{0, 2, 3}}, {{3, 2, 1}}};

    io::write_obj(dir / "plain.obj", mesh);
    TriangleMesh back = io::read_obj(dir / "plain.obj");
    CHECK(back.triangles == mesh.triangles);
    CHECK(back.normals.empty());
    CHECK(back.vertices == mesh.vertices);  // bit-exact coordinates

    mesh.vertices[2] = Vec3d{double(0.1f), 1.0 / 3.0, std::nextafter(0.3, 1.0)};
    mesh.compute_normals();
    io::write_obj(dir / "normals.obj", mesh);
    back = io::read_obj(dir / "normals.obj");
    CHECK(back.triangles == mesh.triangles);
    CHECK(back.vertices == mesh.vertices);
    REQUIRE(back.normals.size() == mesh.normals.size());
    for (std::size_t i = 0; i < mesh.normals.size(); ++i)
        CHECK(freeform::dot(back.normals[i], mesh.normals[i]) == doctest::Approx(1.0).epsilon(1e-15));
    CHECK(contains(read_raw(dir / "normals.obj"), "f 1//1 2//2 3//3"));
}

TEST_CASE("OBJ reader: quads, polygons, index forms, negative indices, normals") {
    TempDir dir;
    write_raw(dir / "forms.obj",
              "# a unit square as a quad, then a pentagon with mixed index forms\r\n"
              "mtllib none.mtl\n"
              "o square\n"
              "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0 1.0\n"
              "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n"
              "vn 0 0 2\n"
              "s off\n"
              "f 1/1/1 2/2/1 3/3/1 4/4/1\n"
              "v 2 0 0   # a trailing comment\n"
              "f -4//1 -1//1 -3//1\n"
              "v 3 0 0\n"
              "f 2/2 5/1 6/3\n"
              "f 1 2 3 4 5\n");
    const TriangleMesh mesh = io::read_obj(dir / "forms.obj");
    REQUIRE(mesh.vertices.size() == 6);
    CHECK(mesh.vertices[3] == Vec3d{0, 1, 0});
    const std::vector<std::array<std::int32_t, 3>> expected = {
        {{0, 1, 2}}, {{0, 2, 3}}, {{1, 4, 2}}, {{1, 4, 5}}, {{0, 1, 2}}, {{0, 2, 3}}, {{0, 3, 4}}};
    CHECK(mesh.triangles == expected);
    CHECK(mesh.normals.empty());  // vertex 6 (and others in 'f 2/2 ...') have no vn

    write_raw(dir / "shared_normal.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 3\nvn 0 0 3\nf 1//1 2//2 3//-1\n");
    const TriangleMesh with_normals = io::read_obj(dir / "shared_normal.obj");
    REQUIRE(with_normals.normals.size() == 3);
    for (const Vec3d& n : with_normals.normals) CHECK(n == Vec3d{0, 0, 1});

    // One vertex with two different normals: normals are dropped.
    write_raw(dir / "split_normal.obj",
              "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nvn 0 0 1\nvn 1 0 0\nf 1//1 2//1 3//1\nf 2//2 4//2 3//2\n");
    CHECK(io::read_obj(dir / "split_normal.obj").normals.empty());
}

TEST_CASE("OBJ reader errors name the file and the line") {
    TempDir dir;
    const std::vector<std::tuple<std::string, std::string, std::string>> cases = {
        {"short_v.obj", "v 0 0 0\nv 1 0\nv 0 1 0\nf 1 2 3\n", "line 2"},
        {"text_v.obj", "v 0 0 0\nv 1 0 0\nv 0 one 0\nf 1 2 3\n", "line 3"},
        {"short_f.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\n\nf 1 2\n", "line 5"},
        {"zero_index.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n", "line 4"},
        {"range.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 2 4\n", "line 5"},
        {"negative.obj", "v 0 0 0\nv 1 0 0\nf -1 -2 -3\nv 0 1 0\n", "line 3"},
        {"normal_range.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nvn 0 0 1\nf 1//1 2//2 3//1\n", "line 5"},
        {"bad_ref.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2/x/ 3\n", "line 4"},
        {"nan.obj", "v 0 0 0\nv 1 0 nan\nv 0 1 0\nf 1 2 3\n", "line 2"},
    };
    for (const auto& c : cases) {
        // Variables, not a structured binding: clang < 16 cannot capture a binding in a lambda.
        const std::string& name = std::get<0>(c);
        const std::string& text = std::get<1>(c);
        const std::string& line = std::get<2>(c);
        CAPTURE(name);
        write_raw(dir / name, text);
        const std::string message = io_error_message([&] { (void)io::read_obj(dir / name); });
        CHECK(contains(message, (dir / name).string()));
        CHECK(contains(message, line));
    }
    write_raw(dir / "no_faces.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\n");
    CHECK(contains(io_error_message([&] { (void)io::read_obj(dir / "no_faces.obj"); }), "no faces"));
    CHECK(contains(io_error_message([&] { (void)io::read_obj(dir / "absent.obj"); }), "absent.obj"));

    TriangleMesh broken;
    broken.vertices = {{0, 0, 0}, {1, 0, 0}};
    broken.triangles = {{{0, 1, 2}}};
    CHECK_THROWS_AS(io::write_obj(dir / "broken.obj", broken), IoError);
    CHECK_THROWS_AS(io::write_stl(dir / "broken.stl", broken), IoError);
    CHECK_FALSE(fs::exists(dir / "broken.obj"));
}

TEST_CASE("STL: binary write, read back welded, facet normals from the geometry") {
    TempDir dir;
    TriangleMesh mesh;  // a tetrahedron (float-representable coordinates)
    mesh.vertices = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0.25, 0.5, 2}};
    mesh.triangles = {{{0, 1, 2}}, {{0, 3, 1}}, {{1, 3, 2}}, {{2, 3, 0}}};
    io::write_stl(dir / "tet.stl", mesh);

    const std::string raw = read_raw(dir / "tet.stl");
    REQUIRE(raw.size() == 84 + 4 * 50);
    CHECK(raw.substr(0, 8) == "freeform");
    CHECK(static_cast<unsigned char>(raw[80]) == 4);
    // First facet (0,0,0), (1,0,0), (0,1,0): normal +z.
    CHECK(float_at(raw, 84) == 0.0f);
    CHECK(float_at(raw, 88) == 0.0f);
    CHECK(float_at(raw, 92) == 1.0f);
    // Second facet (0,0,0), (0.25,0.5,2), (1,0,0): normal along (0, 2, -0.5) normalised.
    const double norm = std::sqrt(4.0 + 0.25);
    CHECK(float_at(raw, 134 + 4) == doctest::Approx(2.0 / norm));
    CHECK(float_at(raw, 134 + 8) == doctest::Approx(-0.5 / norm));
    CHECK(float_at(raw, 134 + 12 + 12) == 0.25f);  // its second vertex

    const TriangleMesh back = io::read_stl(dir / "tet.stl");
    CHECK(back.vertices == mesh.vertices);  // first-seen order matches the original here
    CHECK(back.triangles == mesh.triangles);
    CHECK(back.normals.empty());

    // Truncation is detected.
    write_raw(dir / "cut.stl", raw.substr(0, raw.size() - 10));
    CHECK(contains(io_error_message([&] { (void)io::read_stl(dir / "cut.stl"); }), "truncated"));
    write_raw(dir / "tiny.stl", raw.substr(0, 40));
    CHECK(contains(io_error_message([&] { (void)io::read_stl(dir / "tiny.stl"); }), (dir / "tiny.stl").string()));
    std::string empty = raw.substr(0, 84);
    empty[80] = 0;
    write_raw(dir / "none.stl", empty);
    CHECK_THROWS_AS((void)io::read_stl(dir / "none.stl"), IoError);
}

TEST_CASE("STL: ASCII files are read and welded; a binary header starting with 'solid' still reads as binary") {
    TempDir dir;
    write_raw(dir / "square.stl",
              "solid square\n"
              "  facet normal 0 0 1\n    outer loop\n"
              "      vertex 0 0 0\n      vertex 1 0 0\n      vertex 1 1 0\n"
              "    endloop\n  endfacet\n"
              "  facet normal 0 0 1\n    outer loop\n"
              "      vertex 0 0 0\n      vertex 1.0e+00 1 0\n      vertex -0 1 0\n"
              "    endloop\n  endfacet\n"
              "endsolid square\n");
    const TriangleMesh square = io::read_stl(dir / "square.stl");
    CHECK(square.vertices.size() == 4);
    const std::vector<std::array<std::int32_t, 3>> expected = {{{0, 1, 2}}, {{0, 2, 3}}};
    CHECK(square.triangles == expected);

    write_raw(dir / "bad_ascii.stl", "solid x\nfacet normal 0 0 1\nouter loop\nvertex 0 0\n");
    CHECK(contains(io_error_message([&] { (void)io::read_stl(dir / "bad_ascii.stl"); }), "line 4"));

    TriangleMesh tri;
    tri.vertices = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}};
    tri.triangles = {{{0, 1, 2}}};
    io::write_stl(dir / "tri.stl", tri);
    std::string raw = read_raw(dir / "tri.stl");
    raw.replace(0, 8, "solid   ");
    write_raw(dir / "solid_binary.stl", raw);
    const TriangleMesh back = io::read_stl(dir / "solid_binary.stl");
    CHECK(back.vertices == tri.vertices);
    CHECK(back.triangles == tri.triangles);
}

TEST_CASE("find_font locates DejaVu and reports where it looked") {
    const fs::path bold = io::find_font("DejaVuSans-Bold");
    CHECK(bold.filename() == "DejaVuSans-Bold.ttf");
    CHECK(fs::is_regular_file(bold));
    CHECK(io::find_font("DejaVuSans-Bold.ttf") == bold);
    CHECK(io::find_font(bold.string()) == bold);
    const std::string message = io_error_message([] { (void)io::find_font("NoSuchFont-Regular"); });
    CHECK(contains(message, "NoSuchFont-Regular"));
    CHECK(contains(message, "/usr/share/fonts"));
}

namespace {

struct InkStats {
    double fraction = 0;             // mean coverage
    double centroid_x = 0, centroid_y = 0;
    int x0 = 0, y0 = 0, x1 = -1, y1 = -1;  // pixels with coverage, inclusive
};

InkStats ink_stats(const ImageF& img) {
    InkStats s;
    s.x0 = int(img.cols());
    s.y0 = int(img.rows());
    double total = 0;
    for (int y = 0; y < img.rows(); ++y)
        for (int x = 0; x < img.cols(); ++x) {
            const double v = img(y, x);
            if (v <= 0) continue;
            total += v;
            s.centroid_x += v * (x + 0.5);
            s.centroid_y += v * (y + 0.5);
            s.x0 = std::min(s.x0, x);
            s.x1 = std::max(s.x1, x);
            s.y0 = std::min(s.y0, y);
            s.y1 = std::max(s.y1, y);
        }
    s.fraction = total / double(img.size());
    s.centroid_x /= total;
    s.centroid_y /= total;
    return s;
}

}  // namespace

TEST_CASE("render_text fills the image minus the margin, centred by the ink box") {
    const fs::path font = io::find_font("DejaVuSans-Bold");
    const int width = 240, height = 180;
    const double margin = 0.1;
    const ImageF e = io::render_text("E", font, width, height, margin);
    REQUIRE(e.rows() == height);
    REQUIRE(e.cols() == width);
    CHECK(e.minCoeff() >= 0.0f);
    CHECK(e.maxCoeff() == 1.0f);

    const InkStats s = ink_stats(e);
    CHECK(s.fraction > 0.15);
    CHECK(s.fraction < 0.60);
    // No ink in the margin band (18 px top and bottom, 24 px left and right).
    CHECK(s.x0 >= 24);
    CHECK(s.x1 < width - 24);
    CHECK(s.y0 >= 18);
    CHECK(s.y1 < height - 18);
    // As large as fits: the taller-than-wide 'E' touches the top and bottom margins.
    CHECK(s.y1 - s.y0 + 1 >= height - 2 * 18 - 1);
    // Centred by the ink box; the centroid is centred vertically ('E' is nearly
    // symmetric top to bottom) and lies left of centre (the stem is on the left).
    CHECK(std::abs((s.x0 + s.x1 + 1) / 2.0 - width / 2.0) <= 1.0);
    CHECK(std::abs((s.y0 + s.y1 + 1) / 2.0 - height / 2.0) <= 1.0);
    CHECK(std::abs(s.centroid_y - height / 2.0) <= 3.0);
    CHECK(s.centroid_x < width / 2.0);

    // A symmetric glyph has its centroid at the centre.
    const InkStats o = ink_stats(io::render_text("O", font, 120, 120, 0.05));
    CHECK(std::abs(o.centroid_x - 60) <= 1.5);
    CHECK(std::abs(o.centroid_y - 60) <= 1.5);

    // Longer text is limited by the width instead; '@' renders.
    const InkStats wide = ink_stats(io::render_text("A@b", font, 200, 200, 0.1));
    CHECK(wide.x1 - wide.x0 + 1 >= 200 - 2 * 20 - 1);
    CHECK(wide.x0 >= 20);
    CHECK(wide.x1 < 180);
    CHECK(wide.y1 - wide.y0 + 1 < 160);
}

TEST_CASE("render_text errors") {
    TempDir dir;
    const fs::path font = io::find_font("DejaVuSans");
    CHECK(contains(io_error_message([&] { (void)io::render_text("E", dir / "missing.ttf", 64, 64, 0.1); }),
                   "missing.ttf"));
    write_raw(dir / "fake.ttf", "definitely not a font file");
    CHECK(contains(io_error_message([&] { (void)io::render_text("E", dir / "fake.ttf", 64, 64, 0.1); }),
                   "fake.ttf"));
    CHECK_THROWS_AS((void)io::render_text(" ", font, 64, 64, 0.1), IoError);
    CHECK_THROWS_AS((void)io::render_text("", font, 64, 64, 0.1), IoError);
    CHECK_THROWS_AS((void)io::render_text("\xF3\xA0\x80\x80", font, 64, 64, 0.1), IoError);  // no glyph
    CHECK_THROWS_AS((void)io::render_text("\xC3", font, 64, 64, 0.1), InputError);          // bad UTF-8
    CHECK_THROWS_AS((void)io::render_text("E", font, 0, 64, 0.1), InputError);
    CHECK_THROWS_AS((void)io::render_text("E", font, 64, 64, 0.5), InputError);
}
