// Bounded resources and whole results (issue 25): every reader refuses a request over
// its limit before allocating for it, with a message that names the file and the
// limit; stb_image is handed only files it decodes safely; the run planner refuses scenes whose rays would not fit; StagedOutput moves a
// run's files into place together and puts the previous ones back when it cannot.
#include <doctest/doctest.h>

#include <freeform/design/resources.hpp>
#include <freeform/io.hpp>
#include <freeform/io/scene_file.hpp>
#include <freeform/io/staged_output.hpp>
#include <freeform/io/scene_json.hpp>

#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <random>
#include <string>
#include <utility>
#include <vector>

#include <stb_image_write.h>

#include "files.hpp"
#include "support.hpp"

namespace fs = std::filesystem;
using namespace freeform;

namespace {

using testing::read_raw;
using testing::write_raw;

struct TempDir : testing::TempDir {
    TempDir() : testing::TempDir("freeform_test_limits_") {}
};

// The message of the InputError f throws ("" and a failed check when it throws none).
template <class F>
std::string input_error(F&& f) {
    try {
        f();
    } catch (const InputError& e) {
        return e.what();
    }
    FAIL("did not throw");
    return "";
}

bool contains(const std::string& text, const std::string& part) { return text.find(part) != std::string::npos; }

std::string be32(std::uint32_t v) {
    return {char(v >> 24), char((v >> 16) & 0xff), char((v >> 8) & 0xff), char(v & 0xff)};
}

// CRC-32 (ISO 3309, as PNG uses it), bit by bit.
std::uint32_t crc32_of(const std::string& bytes) {
    std::uint32_t crc = 0xffffffffu;
    for (unsigned char b : bytes) {
        crc ^= b;
        for (int k = 0; k < 8; ++k) crc = (crc >> 1) ^ (0xedb88320u & (0u - (crc & 1u)));
    }
    return ~crc;
}

// A PNG chunk with its length and CRC (so that any reader that checks them accepts it).
std::string png_chunk(const std::string& type, const std::string& data) {
    const std::string body = type + data;
    return be32(std::uint32_t(data.size())) + body + be32(crc32_of(body));
}

// A well-formed PNG header announcing width × height grey pixels, with one tiny IDAT: a
// reader that trusts the header allocates width × height bytes before finding out.
std::string png_announcing(std::uint32_t width, std::uint32_t height) {
    const std::string ihdr = be32(width) + be32(height) + std::string{8, 0, 0, 0, 0};
    return std::string("\x89PNG\r\n\x1a\n", 8) + png_chunk("IHDR", ihdr) + png_chunk("IDAT", std::string(8, '\0')) +
           png_chunk("IEND", "");
}

std::string stl_binary(std::uint32_t announced, std::uint32_t stored) {
    std::string bytes(80, ' ');
    for (int k = 0; k < 4; ++k) bytes.push_back(char((announced >> (8 * k)) & 0xff));
    for (std::uint32_t t = 0; t < stored; ++t) {
        std::string record(50, '\0');
        const float corner[3][3] = {{0, 0, 0}, {1, 0, float(t)}, {0, 1, 0}};
        for (int v = 0; v < 3; ++v) std::memcpy(record.data() + 12 + 12 * v, corner[v], 12);
        bytes += record;
    }
    return bytes;
}

}  // namespace

TEST_CASE("file size: refused before reading, naming the file and the limit") {
    TempDir dir;
    write_raw(dir / "big.pfm", std::string(5000, ' '));
    Limits small;
    small.data_file_bytes = 4096;
    const std::string m = input_error([&] { (void)io::read_pfm(dir / "big.pfm", small); });
    CHECK(contains(m, (dir / "big.pfm").string()));
    CHECK(contains(m, "data_file_bytes = 4 KiB"));
    CHECK(contains(m, "4.88 KiB"));
    // At the limit the file is read (and then found to be a bad PFM: an IoError).
    small.data_file_bytes = 5000;
    CHECK_THROWS_AS((void)io::read_pfm(dir / "big.pfm", small), IoError);
    // Scene files have their own, smaller limit.
    write_raw(dir / "scene.json", "{}" + std::string(3000, ' '));
    small.scene_file_bytes = 2048;
    CHECK(contains(input_error([&] { (void)io::load_scene(dir / "scene.json", small); }), "scene_file_bytes"));
}

TEST_CASE("pixels: image and PFM headers are checked before decoding") {
    TempDir dir;
    // 20,000 x 20,000 grey pixels announced in a 70-byte file: 400 MB if decoded (stb
    // itself refuses sizes over 2^31 bytes as "too large").
    write_raw(dir / "huge.png", png_announcing(20000, 20000));
    const std::string m = input_error([&] { (void)io::read_image_grey(dir / "huge.png"); });
    CHECK(contains(m, "huge.png"));
    CHECK(contains(m, "20000 x 20000 pixels"));
    CHECK(contains(m, "the limit pixels = 67108864"));
    write_raw(dir / "huger.png", png_announcing(100000, 100000));
    CHECK(contains(input_error([&] { (void)io::read_image_grey(dir / "huger.png"); }), "huger.png"));

    write_raw(dir / "huge.pfm", "Pf\n1000000 1000000\n-1\n" + std::string(16, '\0'));
    CHECK(contains(input_error([&] { (void)io::read_pfm(dir / "huge.pfm"); }), "1000000 x 1000000 pixels"));
    // Through read_image_grey (the target reader) too.
    CHECK(contains(input_error([&] { (void)io::read_image_grey(dir / "huge.pfm"); }), "limit pixels"));

    // A real 40 x 30 image passes a limit of 1200 pixels and fails one of 1199.
    ImageF img(30, 40);
    img.setConstant(0.5f);
    io::write_png(dir / "small.png", img);
    Limits limits;
    limits.pixels = 1200;
    CHECK(io::read_image_grey(dir / "small.png", limits).cols() == 40);
    limits.pixels = 1199;
    CHECK(contains(input_error([&] { (void)io::read_image_grey(dir / "small.png", limits); }), "40 x 30 pixels"));
}

TEST_CASE("triangles: STL and OBJ counted before the mesh is built") {
    Limits limits;
    limits.triangles = 3;
    const TriangleMesh four = io::parse_stl(stl_binary(4, 4), "four.stl");
    CHECK(four.triangles.size() == 4);
    CHECK(contains(input_error([&] { (void)io::parse_stl(stl_binary(4, 4), "four.stl", limits); }),
                   "STL file 'four.stl': 4 triangles, over the limit triangles = 3"));
    // A header that announces four billion triangles in a short file: refused as truncated.
    CHECK_THROWS_AS((void)io::parse_stl(stl_binary(0xffffffffu, 1), "liar.stl"), IoError);

    std::string ascii = "solid s\n";
    for (int t = 0; t < 4; ++t)
        ascii += "facet normal 0 0 1\nouter loop\nvertex 0 0 " + std::to_string(t) +
                 "\nvertex 1 0 0\nvertex 0 1 0\nendloop\nendfacet\n";
    ascii += "endsolid s\n";
    CHECK(io::parse_stl(ascii, "a.stl").triangles.size() == 4);
    CHECK(contains(input_error([&] { (void)io::parse_stl(ascii, "a.stl", limits); }), "ASCII STL file 'a.stl': 4"));

    // A pentagon fans into 3 triangles, a quad into 2: 5 in all.
    const std::string obj = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv -1 0.5 0\nf 1 2 3 4 5\nf 1 2 3 4\n";
    CHECK(io::parse_obj(obj, "m.obj").triangles.size() == 5);
    limits.triangles = 4;
    CHECK(contains(input_error([&] { (void)io::parse_obj(obj, "m.obj", limits); }), "5 triangles"));
    limits.triangles = 1;  // 5 vertex records > 3 x 1
    CHECK(contains(input_error([&] { (void)io::parse_obj("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 1\nf 1 2 3\n", "v.obj",
                                                         limits); }),
                   "4 vertex records"));
}

TEST_CASE("json_depth: nested brackets refused in one pass, with the position") {
    const std::string nested = std::string(200000, '[') + std::string(200000, ']');
    const std::string m = input_error([&] { (void)io::parse_scene(nested, "deep.json", {}); });
    CHECK(contains(m, "deep.json: arrays and objects nested deeper than 64 levels at line 1, column 65"));
    CHECK(contains(m, "json_depth = 64"));

    // Brackets inside strings and comments do not count; 64 levels pass the check.
    const std::string quiet =
        "{\"name\": \"[[[[[[[[[[\", /* {{{{{{{{ */ \"light\": {\"type\": \"collimated\"}, \"surface\": {}, "
        "// [[[[\n \"receiver\": {}}";
    Limits tight;
    tight.json_depth = 2;
    CHECK(io::parse_scene(quiet, "q.json", {}, tight).name == "[[[[[[[[[[");
    tight.json_depth = 1;
    const std::size_t light = quiet.find("{\"type");
    CHECK(contains(input_error([&] { (void)io::parse_scene(quiet, "q.json", {}, tight); }),
                   "line 1, column " + std::to_string(light + 1)));
    const std::string at_limit = std::string(64, '[') + std::string(64, ']');
    CHECK(contains(input_error([&] { (void)io::parse_scene(at_limit, "s.json", {}); }), "s.json: scene: expected an object"));

    // With the depth check raised, a deep file still parses (the duplicate-key check keeps
    // one key per level and builds a path only for its message; tests/cli/hostile.py
    // watches the memory of the command line on such files).
    Limits raised;
    raised.json_depth = 1 << 20;
    CHECK(contains(input_error([&] { (void)io::parse_scene(nested, "deep.json", {}, raised); }), "expected an object"));
    CHECK(contains(input_error([&] {
                       (void)io::parse_scene("{\"a\": [1, {\"b\": {\"c\": 1, \"c\": 2}}]}", "d.json", {});
                   }),
                   "d.json: a[1].b.c: duplicate key"));
}

TEST_CASE("memory plan: a scene's rays are weighed before they are made") {
    DesignJob job{testing::basic_scene(200, 16), {}};
    Scene& scene = job.scene;
    scene.target = TargetSpec{};
    scene.target->text = "E";
    const ResourcePlan render = plan_resources(job, RunKind::render, 2);
    const ResourcePlan design = plan_resources(job, RunKind::design, 2);
    // 640,000 rays of the light (80 bytes each in a render) plus 64 per cell for the
    // cell means; a design keeps more per ray and exports up to 2 M triangles.
    CHECK(render.rays == 2'560'000);
    CHECK(render.bytes > 640000.0 * 80);
    CHECK(render.bytes < 1.0e9);
    CHECK(design.bytes > render.bytes);
    CHECK(design.bytes < 2.0e9);
    CHECK_NOTHROW(check_resources(job, RunKind::design, 2, Limits{}));

    // 2^20 rays per cell on a 16384² receiver: 2.8e14 rays.
    scene.receiver.width = scene.receiver.height = 16384;
    scene.light.rays_per_cell = 1 << 20;
    const std::string m = input_error([&] { (void)check_resources(job, RunKind::render, 2, Limits{}); });
    CHECK(contains(m, "the render would need about"));
    CHECK(contains(m, "2.81e+14 rays"));
    CHECK(contains(m, "over the limit memory_bytes = 16 GiB"));
    // A raised limit lets it through (the plan itself allocates nothing).
    Limits huge;
    huge.memory_bytes = ~std::uint64_t(0);
    CHECK_NOTHROW(check_resources(job, RunKind::render, 2, huge));
}

TEST_CASE("StagedOutput: all new files or all previous ones") {
    TempDir dir;
    const fs::path out = dir / "out";
    const auto staging_folders = [&] {
        int n = 0;
        for (const auto& e : fs::directory_iterator(out))
            n += e.path().filename().string().rfind(io::StagedOutput::staging_prefix, 0) == 0;
        return n;
    };
    const auto write_text = [](const std::string& text) {
        return [text](const fs::path& f) { io::write_file_atomically(f, text); };
    };

    SUBCASE("commit moves every file into place, metrics.json included") {
        {
            io::StagedOutput s(out);
            s.write("metrics.json", write_text("{\"run\": 1}"));
            s.write("a.txt", write_text("a1"));
            CHECK(!fs::exists(out / "a.txt"));  // nothing in place before the commit
            CHECK(staging_folders() == 1);
            s.commit();
        }
        CHECK(read_raw(out / "a.txt") == "a1");
        CHECK(read_raw(out / "metrics.json") == "{\"run\": 1}");
        CHECK(staging_folders() == 0);
        // A second run replaces them; a run that never commits leaves nothing.
        {
            io::StagedOutput s(out);
            s.write("a.txt", write_text("a2"));
            s.write("metrics.json", write_text("{\"run\": 2}"));
            s.commit();
        }
        CHECK(read_raw(out / "a.txt") == "a2");
        {
            io::StagedOutput s(out);
            s.write("a.txt", write_text("a3"));
        }
        CHECK(read_raw(out / "a.txt") == "a2");
        CHECK(staging_folders() == 0);
    }
    SUBCASE("a failed commit puts the previous files back and names the file") {
        {
            io::StagedOutput s(out);
            s.write("a.txt", write_text("old a"));
            s.write("b.txt", write_text("old b"));
            s.write("metrics.json", write_text("old"));
            s.commit();
        }
        fs::remove(out / "b.txt");
        fs::create_directories(out / "b.txt" / "in-the-way");  // a folder where a file must go
        io::StagedOutput s(out);
        s.write("a.txt", write_text("new a"));
        s.write("b.txt", write_text("new b"));
        s.write("metrics.json", write_text("new"));
        try {
            s.commit();
            FAIL("commit did not throw");
        } catch (const IoError& e) {
            CHECK(contains(e.what(), (out / "b.txt").string()));
        }
        CHECK(read_raw(out / "a.txt") == "old a");
        CHECK(read_raw(out / "metrics.json") == "old");
        CHECK(fs::is_directory(out / "b.txt" / "in-the-way"));  // the user's folder is never moved
    }
    SUBCASE("a writer's error names the output file, not the staged one") {
        io::StagedOutput s(out);
        ImageF empty;
        try {
            s.write("heightmap.pfm", [&](const fs::path& f) { io::write_pfm(f, empty); });
            FAIL("write did not throw");
        } catch (const IoError& e) {
            CHECK(contains(e.what(), "'" + (out / "heightmap.pfm").string() + "'"));
            CHECK(!contains(e.what(), io::StagedOutput::staging_prefix));
        }
        CHECK_THROWS_AS(s.write("../escape.txt", write_text("x")), InputError);
    }
    SUBCASE("the staging folder of a process that is gone is removed by the next run") {
        fs::create_directories(out / (std::string(io::StagedOutput::staging_prefix) + "999999999-1") / ".previous");
        io::StagedOutput s(out);
        CHECK(staging_folders() == 1);  // its own only
    }
}

TEST_CASE("image structure: stb_image sees only files of the formats it decodes safely") {
    TempDir dir;
    // Real files of every accepted format decode.
    std::vector<unsigned char> grey(48 * 32);
    for (std::size_t k = 0; k < grey.size(); ++k) grey[k] = static_cast<unsigned char>((k * 37) % 251);
    REQUIRE(stbi_write_jpg((dir / "a.jpg").string().c_str(), 48, 32, 1, grey.data(), 90));
    REQUIRE(stbi_write_bmp((dir / "a.bmp").string().c_str(), 48, 32, 1, grey.data()));
    std::string pgm = "P5\n# a comment\n48 32\n255\n";
    pgm.append(reinterpret_cast<const char*>(grey.data()), grey.size());
    write_raw(dir / "a.pgm", pgm);
    for (const char* name : {"a.jpg", "a.bmp", "a.pgm"}) {
        INFO(name);
        const ImageF img = io::read_image_grey(dir / name);
        CHECK(img.cols() == 48);
        CHECK(img.rows() == 32);
    }
    CHECK(io::read_image_grey(dir / "a.pgm")(0, 1) == doctest::Approx(37.0 / 255.0));

    // The inputs that made stb write out of bounds or step into undefined behaviour under
    // the fuzzer are refused before stb sees them, each for its reason.
    const fs::path found = fs::path(FREEFORM_SOURCE_DIR) / "tests" / "fuzz" / "regressions" / "image";
    const std::pair<const char*, const char*> refused[] = {
        {"stb-jpeg-dht-counts-over-256.jpg", "a JPEG segment runs past the end"},
        {"stb-png-empty-idat-memcpy-null.png", "a PNG chunk runs past the end"},
        {"stb-pnm-width-int-overflow.ppm", "oversized number"},
        {"stb-psd-matte-float-to-uchar.psd", "not a PNG, JPEG, BMP"},
        {"stb-hdr-rle-endless-loop.hdr", "a Radiance HDR image (not taken"},
        {"stb-jpeg-progressive-undefined-ac-table.jpg", "a JPEG scan that uses an undefined Huffman table"},
        {"stb-jpeg-ac-table-before-its-dht.jpg", "a JPEG scan that uses an undefined Huffman table"},
    };
    for (const auto& entry : refused) {
        const std::string name = entry.first, reason = entry.second;  // clang 14: no lambda capture of bindings
        INFO(name);
        const std::string m = input_error([&] { (void)io::read_image_grey(found / name); });
        CHECK(contains(m, name));
        CHECK(contains(m, reason));
    }
    // The scan check lets real files through: baseline, progressive (DC scans name AC
    // tables they do not use) and chroma-subsampled JPEGs from an encoder decode.
    const fs::path seeds = fs::path(FREEFORM_SOURCE_DIR) / "tests" / "fuzz" / "corpus" / "image";
    for (const char* name : {"baseline-16x8.jpg", "progressive-16x8.jpg", "subsampled-16x16.jpg", "grey-8x8.jpg"}) {
        INFO(name);
        CHECK(io::detail::image_structure_problem(read_raw(seeds / name)).empty());
        CHECK(io::read_image_grey(seeds / name).size() > 0);
    }
    // A Huffman table of 257 codes made by hand (SOI, DHT with counts 15 x 16 + 17), and a
    // PNG whose first IDAT is empty, whole.
    std::string jpeg = "\xFF\xD8\xFF\xC4";
    std::string table(1, '\0');
    for (int k = 0; k < 16; ++k) table.push_back(char(k == 15 ? 17 : 16));
    table.append(257, '\0');
    jpeg += std::string{char((table.size() + 2) >> 8), char((table.size() + 2) & 0xff)} + table + "\xFF\xD9";
    CHECK(contains(input_error([&] { (void)io::decode_image_grey(jpeg, "h.jpg"); }), "more than 256 codes"));
    std::string png("\x89PNG\r\n\x1a\n", 8);
    const char empty_idat[] = "\0\0\0\0IDAT\x35\xaf\x06\x1e";
    png += std::string("\0\0\0\x0dIHDR\0\0\0\x05\0\0\0\x04\x10\0\0\0\0\x33\xc8\x76\xdf", 25) +
           std::string(empty_idat, 12) + std::string("\0\0\0\0IEND\xae\x42\x60\x82", 12);
    CHECK(contains(input_error([&] { (void)io::decode_image_grey(png, "e.png"); }), "an empty PNG IDAT chunk"));
    // A real JPEG whose frame header is changed to announce 8000 x 8000 pixels (stb would
    // decode it, filling what is missing with zeros: 440 MB for a 2 KB file).
    std::string forged = read_raw(dir / "a.jpg");
    const std::size_t sof = forged.find("\xFF\xC0");
    REQUIRE(sof != std::string::npos);
    forged[sof + 5] = char(8000 >> 8), forged[sof + 6] = char(8000 & 0xff);
    forged[sof + 7] = char(8000 >> 8), forged[sof + 8] = char(8000 & 0xff);
    CHECK(contains(input_error([&] { (void)io::decode_image_grey(forged, "f.jpg"); }),
                   "announces 8000 x 8000 pixels in"));
    // GIF, TGA (no signature) and PSD are not taken.
    CHECK(contains(input_error([&] { (void)io::decode_image_grey("GIF89a\x01\x00\x01\x00", "g.gif"); }),
                   "not a PNG, JPEG"));
}
