// Scene files: parsing and validation (io/scene_json.hpp), file loading and the initial
// surface (io/scene_file.hpp).
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include <doctest/doctest.h>
#include <freeform/io/pfm.hpp>
#include <freeform/io/scene_file.hpp>
#include <freeform/io/scene_json.hpp>

using nlohmann::json;
namespace fs = std::filesystem;
using namespace freeform;

namespace {

json minimal_scene() {
    return json::parse(R"({
        "light": {"type": "collimated"},
        "surface": {},
        "receiver": {}
    })");
}

json full_scene() {
    return json::parse(R"({
        "$schema": "freeform-scene",
        "comment": "every key set",
        "_note": ["comments", "may", "hold", "anything"],
        "name": "full",
        "description": "all keys",
        "light": {"type": "collimated", "direction": [0.1, 0, -1], "rays_per_cell": 4, "rays": 5000},
        "surface": {"center": [0.01, 0.02, 0.03], "normal": [0, 0, 2], "up": [0, 3, 0],
                    "size": [0.12, 0.08], "mesh": [61, 41], "height_bounds": [-0.002, 0.004],
                    "aperture": "ellipse", "material": {"refractive": 1.5, "thickness": 0.02},
                    "phong_alpha": 0.6, "initial": {"paraboloid": {"focal_length": 0.7}}},
        "receiver": {"center": [0, 0, -0.4], "normal": [0, 0, 1], "up": [1, 0, 0],
                     "size": [0.3, 0.25], "resolution": [120, 100], "deposit": "nearest"},
        "target": {"text": "Q", "font": "DejaVuSans", "margin": 0.2},
        "meshes": [{"file": "walls.obj", "material": "mirror"}, {"file": "/abs/block.obj"},
                   {"file": "prism.obj", "material": {"refractive": 1.52}}],
        "trace": {"tracer": "embree", "max_depth": 12},
        "optimize": {"time_budget": 2.5, "seed": 42, "max_iterations": 1000, "target_error": 0.05, "threads": 3}
    })");
}

// The message of the InputError that parsing `j` throws ("" when it does not throw).
std::string parse_error(const json& j, const fs::path& base = {}) {
    try {
        (void)scene_from_json(j, base);
    } catch (const InputError& e) {
        return e.what();
    }
    return "";
}

bool starts_with(const std::string& s, const std::string& prefix) { return s.rfind(prefix, 0) == 0; }

// A fresh directory under the system temp dir, removed at the end of the test.
struct TempDir {
    fs::path path;
    TempDir() {
        std::random_device rd;
        path = fs::temp_directory_path() / ("freeform_scene_test_" + std::to_string(rd()) + std::to_string(rd()));
        fs::create_directories(path);
    }
    ~TempDir() {
        std::error_code ec;
        fs::remove_all(path, ec);
    }
    fs::path write(const std::string& name, const std::string& text) const {
        const fs::path p = path / name;
        std::ofstream(p, std::ios::binary) << text;
        return p;
    }
};

}  // namespace

TEST_CASE("a minimal scene gets every documented default") {
    const Scene s = scene_from_json(minimal_scene());
    const auto& c = std::get<CollimatedLight>(s.light.shape);
    CHECK(c.direction == Vec3d{0, 0, -1});
    CHECK(s.light.rays_per_cell == 16);
    CHECK(s.light.rays == 0);

    CHECK(s.surface.frame.origin == Vec3d{0, 0, 0});
    CHECK(s.surface.frame.w == Vec3d{0, 0, 1});
    CHECK(s.surface.frame.v == Vec3d{0, 1, 0});
    CHECK(s.surface.frame.u == Vec3d{1, 0, 0});
    CHECK(s.surface.size.x == 0.1);
    CHECK(s.surface.size.y == 0.1);
    CHECK(s.surface.nx == 0);  // "auto": chosen from the case by the designer
    CHECK(s.surface.ny == 0);
    CHECK(s.surface.h_min == -0.005);
    CHECK(s.surface.h_max == 0.005);
    CHECK(s.surface.aperture == Aperture::rect);
    CHECK(std::holds_alternative<Mirror>(s.surface.material));
    CHECK(s.surface.phong_alpha == 0.5);  // docs/scene.md: ½ since issue 13
    CHECK(s.surface.initial_pfm.empty());
    CHECK_FALSE(s.surface.initial_paraboloid.has_value());

    CHECK(s.receiver.frame.origin == Vec3d{0, 0, 0.5});
    CHECK(s.receiver.frame.w == Vec3d{0, 0, -1});
    CHECK(s.receiver.frame.v == Vec3d{0, 1, 0});
    CHECK(s.receiver.frame.u == Vec3d{-1, 0, 0});  // u = v x w
    CHECK(s.receiver.size.x == 0.2);
    CHECK(s.receiver.width == 200);
    CHECK(s.receiver.height == 200);
    CHECK(s.receiver.deposit == Deposit::fine_bilinear);

    CHECK_FALSE(s.target.has_value());
    CHECK(s.meshes.empty());
    CHECK(s.trace.tracer == TracerChoice::automatic);
    CHECK(s.trace.max_depth == 8);
    const DesignOptions o = job_from_json(minimal_scene()).options;
    CHECK(o.time_budget == 60);
    CHECK(o.seed == 1);
    CHECK(o.max_iterations == 0);
    CHECK(o.target_error == 0);
    CHECK(o.threads == 0);
    CHECK(s.name.empty());
}

TEST_CASE("a full scene parses with the values it states") {
    const Scene s = scene_from_json(full_scene(), "/scenes/here");
    CHECK(s.name == "full");
    CHECK(s.description == "all keys");
    CHECK(std::get<CollimatedLight>(s.light.shape).direction == Vec3d{0.1, 0, -1});
    CHECK(s.light.rays_per_cell == 4);
    CHECK(s.light.rays == 5000);

    CHECK(s.surface.frame.origin == Vec3d{0.01, 0.02, 0.03});
    CHECK(s.surface.frame.w == Vec3d{0, 0, 1});  // normalised
    CHECK(s.surface.frame.v == Vec3d{0, 1, 0});
    CHECK(s.surface.size.x == 0.12);
    CHECK(s.surface.size.y == 0.08);
    CHECK(s.surface.nx == 61);
    CHECK(s.surface.ny == 41);
    CHECK(s.surface.h_min == -0.002);
    CHECK(s.surface.h_max == 0.004);
    CHECK(s.surface.aperture == Aperture::ellipse);
    const auto& lens = std::get<Lens>(s.surface.material);
    CHECK(lens.ior == 1.5);
    CHECK(lens.thickness == 0.02);
    CHECK(lens.rim < 0);  // "auto" when left out
    CHECK(s.surface.phong_alpha == 0.6);
    REQUIRE(s.surface.initial_paraboloid.has_value());
    CHECK(s.surface.initial_paraboloid->focal_length == 0.7);

    CHECK(s.receiver.frame.origin == Vec3d{0, 0, -0.4});
    CHECK(s.receiver.frame.w == Vec3d{0, 0, 1});
    CHECK(s.receiver.frame.v == Vec3d{1, 0, 0});
    CHECK(s.receiver.frame.u == Vec3d{0, -1, 0});  // u = v x w = x × z = -y
    CHECK(s.receiver.size.y == 0.25);
    CHECK(s.receiver.width == 120);
    CHECK(s.receiver.height == 100);
    CHECK(s.receiver.deposit == Deposit::nearest);

    REQUIRE(s.target.has_value());
    CHECK(s.target->text == "Q");
    CHECK(s.target->font == "DejaVuSans");
    CHECK(s.target->margin == 0.2);
    CHECK(s.target->image.empty());

    REQUIRE(s.meshes.size() == 3);
    CHECK(s.meshes[0].file == fs::path("/scenes/here/walls.obj"));
    CHECK(s.meshes[0].material.is_mirror());
    CHECK(s.meshes[1].file == fs::path("/abs/block.obj"));
    CHECK(s.meshes[1].material.kind == MeshKind::absorber);
    CHECK(s.meshes[2].material.is_refractive());
    CHECK(s.meshes[2].material.ior == 1.52);
    CHECK(s.base_dir == fs::path("/scenes/here"));

    CHECK(s.trace.tracer == TracerChoice::embree);
    CHECK(s.trace.max_depth == 12);
    const DesignOptions o = job_from_json(full_scene(), "/scenes/here").options;
    CHECK(o.time_budget == 2.5);
    CHECK(o.seed == 42);
    CHECK(o.max_iterations == 1000);
    CHECK(o.target_error == 0.05);
    CHECK(o.threads == 3);
}

TEST_CASE("other light types, a PFM initial surface and an image target") {
    json j = minimal_scene();
    j["light"] = json::parse(R"({"type": "point", "position": [0, 0.01, 0.3], "axis": [0, 0, -1],
                                 "profile": [[0, 1], [30, 0.5], [60, 0]], "rays": 100})");
    j["surface"]["initial"] = "start/h.PFM";
    j["target"] = {{"image", "E.png"}};
    Scene s = scene_from_json(j, "/base");
    const auto& p = std::get<PointLight>(s.light.shape);
    CHECK(p.position == Vec3d{0, 0.01, 0.3});
    CHECK(p.axis == Vec3d{0, 0, -1});
    REQUIRE(p.profile.size() == 3);
    CHECK(p.profile[1] == std::pair<double, double>{30, 0.5});
    CHECK(s.light.rays == 100);
    CHECK(s.surface.initial_pfm == fs::path("/base/start/h.PFM"));
    CHECK(s.target->image == fs::path("/base/E.png"));
    CHECK(s.target->fit == freeform::TargetFit::stretch);  // the default
    j["target"]["fit"] = "contain";
    CHECK(scene_from_json(j, "/base").target->fit == freeform::TargetFit::contain);
    j["target"]["fit"] = "cover";
    CHECK(scene_from_json(j, "/base").target->fit == freeform::TargetFit::cover);
    j["target"].erase("fit");

    j["light"] = json::parse(R"({"type": "disk", "center": [0, 0, 0.4], "radius": 0.003})");
    s = scene_from_json(j);
    const auto& d = std::get<DiskLight>(s.light.shape);
    CHECK(d.center == Vec3d{0, 0, 0.4});
    CHECK(d.normal == Vec3d{0, 0, -1});
    CHECK(d.radius == 0.003);
    // Without a base directory, file names stay as written (relative to the working directory).
    CHECK(s.surface.initial_pfm == fs::path("start/h.PFM"));

    // The point light's axis defaults to zero, meaning "towards the surface centre".
    j["light"] = json::parse(R"({"type": "point", "position": [0, 0, 0.3]})");
    CHECK(std::get<PointLight>(scene_from_json(j).light.shape).axis == Vec3d{0, 0, 0});
}

TEST_CASE("frames follow u = v x w") {
    json j = minimal_scene();
    j["receiver"]["center"] = {0, 0, -0.5};  // below the surface, facing it
    j["receiver"]["normal"] = {0, 0, 1};
    j["receiver"]["up"] = {1, 0, 0};
    j["light"] = json::parse(R"({"type": "collimated"})");
    const Scene s = scene_from_json(j);
    // v = x, w = z: u = x × z = -y.
    CHECK(s.receiver.frame.u.x == doctest::Approx(0));
    CHECK(s.receiver.frame.u.y == doctest::Approx(-1));
    CHECK(s.receiver.frame.u.z == doctest::Approx(0));
}

TEST_CASE("every class of bad input throws InputError naming the key") {
    struct Case {
        const char* what;
        json patch;  // merged into the minimal scene (RFC 7386; null removes a key)
        std::string expected_prefix;
        std::string expected_text;
    };
    const double inf = std::numeric_limits<double>::infinity();
    const std::vector<Case> cases = {
        {"missing light", {{"light", nullptr}}, "light: ", "missing required key"},
        {"missing surface", {{"surface", nullptr}}, "surface: ", "missing required key"},
        {"missing receiver", {{"receiver", nullptr}}, "receiver: ", "missing required key"},
        {"missing light type",
         {{"light", {{"type", nullptr}, {"direction", {0, 0, -1}}}}},
         "light.type: ",
         "missing required key"},
        {"missing point position", {{"light", {{"type", "point"}}}}, "light.position: ", "missing required key"},
        {"missing disk radius",
         {{"light", {{"type", "disk"}, {"center", {0, 0, 1}}}}},
         "light.radius: ",
         "missing required key"},
        {"unknown top key", {{"recever", json::object()}}, "recever: ", "did you mean 'receiver'?"},
        {"unknown key with hint",
         {{"receiver", {{"resolutin", {10, 10}}}}},
         "receiver.resolutin: ",
         "unknown key (did you mean 'resolution'?)"},
        {"unknown key without hint", {{"surface", {{"zzzzzzzz", 1}}}}, "surface.zzzzzzzz: ", "unknown key"},
        {"key of another light type",
         {{"light", {{"position", {0, 0, 1}}}}},
         "light.position: ",
         "not a key of a collimated light"},
        {"empty key", {{"light", {{"type", "point"}, {"position", {0, 0, 1}}, {"", 1}}}}, "light.: ", "unknown key"},
        {"unknown light type",
         {{"light", {{"type", "laser"}}}},
         "light.type: ",
         R"(must be one of "collimated", "point", "disk", got "laser")"},
        {"wrong type",
         {{"light", {{"direction", "down"}}}},
         "light.direction: ",
         R"(expected an array of 3 numbers, got "down")"},
        {"wrong element type", {{"light", {{"direction", {0, "0", -1}}}}}, "light.direction[1]: ", "expected a number"},
        {"wrong array length",
         {{"surface", {{"size", {0.1, 0.1, 0.1}}}}},
         "surface.size: ",
         "expected an array of 2 numbers"},
        {"object expected", {{"surface", {1, 2}}}, "surface: ", "expected an object, got an array of 2 elements"},
        {"infinite number", {{"surface", {{"size", {0.1, inf}}}}}, "surface.size[1]: ", "finite"},
        {"NaN", {{"receiver", {{"center", {0, std::nan(""), 0.5}}}}}, "receiver.center[1]: ", "finite"},
        {"negative size", {{"surface", {{"size", {0.1, -0.1}}}}}, "surface.size[1]: ", "must be > 0, got -0.1"},
        {"zero receiver size", {{"receiver", {{"size", {0, 0.1}}}}}, "receiver.size[0]: ", "must be > 0"},
        {"inverted bounds", {{"surface", {{"height_bounds", {0.01, -0.01}}}}}, "surface.height_bounds: ", "inverted"},
        {"empty bounds", {{"surface", {{"height_bounds", {0.01, 0.01}}}}}, "surface.height_bounds: ", "inverted"},
        {"degenerate frame", {{"surface", {{"up", {0, 0, 5}}}}}, "surface.up", "parallel"},
        {"zero normal", {{"receiver", {{"normal", {0, 0, 0}}}}}, "receiver.normal: ", "non-zero"},
        {"zero direction", {{"light", {{"direction", {0, 0, 0}}}}}, "light.direction: ", "non-zero"},
        {"light from behind", {{"light", {{"direction", {0, 0, 1}}}}}, "light.direction: ", "towards"},
        {"grazing light", {{"light", {{"direction", {1, 0, 0}}}}}, "light.direction: ", "towards"},
        {"point light behind",
         {{"light", {{"type", "point"}, {"position", {0, 0, -0.3}}}}},
         "light.position: ",
         "in front"},
        {"disk inside slab",
         {{"light", {{"type", "disk"}, {"center", {0, 0, 0.001}}, {"radius", 0.01}}}},
         "light.center: ",
         "in front"},
        {"bad enum", {{"surface", {{"aperture", "circle"}}}}, "surface.aperture: ", R"("rect", "ellipse")"},
        {"bad deposit", {{"receiver", {{"deposit", 3}}}}, "receiver.deposit: ", R"("fine_bilinear", "bilinear", "nearest")"},
        {"bad tracer", {{"trace", {{"tracer", "optix"}}}}, "trace.tracer: ", R"("auto", "heightfield", "embree")"},
        {"mesh too small", {{"surface", {{"mesh", {1, 10}}}}}, "surface.mesh[0]: ", "must be an integer in [2, "},
        {"negative mesh", {{"surface", {{"mesh", {10, -5}}}}}, "surface.mesh[1]: ", "got -5"},
        {"huge mesh", {{"surface", {{"mesh", {10, 1e12}}}}}, "surface.mesh[1]: ", "must be an integer"},
        {"fractional mesh", {{"surface", {{"mesh", {10.5, 10}}}}}, "surface.mesh[0]: ", "expected an integer"},
        {"zero resolution",
         {{"receiver", {{"resolution", {0, 10}}}}},
         "receiver.resolution[0]: ",
         "in [1, 16384], got 0"},
        {"max_depth range", {{"trace", {{"max_depth", 65}}}}, "trace.max_depth: ", "[1, 64]"},
        {"negative seed", {{"optimise", {{"seed", -1}}}}, "optimise.seed: ", ">= 0"},
        {"fractional seed", {{"optimise", {{"seed", 1.5}}}}, "optimise.seed: ", "expected an integer"},
        {"zero budget", {{"optimise", {{"time_budget", 0}}}}, "optimise.time_budget: ", "> 0"},
        {"unknown bandit", {{"optimise", {{"bandit", "greedy"}}}}, "optimise.bandit: ", "\"history\""},
        {"target error 1", {{"optimise", {{"target_error", 1}}}}, "optimise.target_error: ", "[0, 1)"},
        {"negative threads", {{"optimise", {{"threads", -2}}}}, "optimise.threads: ", "in [0, 65536], got -2"},
        {"unknown optimise key",
         {{"optimise", {{"time_budjet", 5}}}},
         "optimise.time_budjet: ",
         "did you mean 'time_budget'?"},
        {"both spellings", {{"optimise", json::object()}, {"optimize", json::object()}}, "optimize: ", "not both"},
        {"rays zero", {{"light", {{"rays", 0}}}}, "light.rays: ", "must be an integer in [1, "},
        {"rays_per_cell negative", {{"light", {{"rays_per_cell", -3}}}}, "light.rays_per_cell: ", "> 0"},
        {"profile short",
         {{"light", {{"type", "point"}, {"position", {0, 0, 1}}, {"profile", {{0, 1}}}}}},
         "light.profile: ",
         "at least 2"},
        {"profile order",
         {{"light", {{"type", "point"}, {"position", {0, 0, 1}}, {"profile", {{0, 1}, {20, 1}, {10, 1}}}}}},
         "light.profile[2][0]: ",
         "strictly increasing"},
        {"profile angle",
         {{"light", {{"type", "point"}, {"position", {0, 0, 1}}, {"profile", {{0, 1}, {190, 1}}}}}},
         "light.profile[1][0]: ",
         "[0, 180]"},
        {"profile intensity",
         {{"light", {{"type", "point"}, {"position", {0, 0, 1}}, {"profile", {{0, 1}, {10, -1}}}}}},
         "light.profile[1][1]: ",
         ">= 0"},
        {"profile dark",
         {{"light", {{"type", "point"}, {"position", {0, 0, 1}}, {"profile", {{0, 0}, {10, 0}}}}}},
         "light.profile: ",
         "zero"},
        {"disk radius", {{"light", {{"type", "disk"}, {"center", {0, 0, 1}}, {"radius", 0}}}}, "light.radius: ", "> 0"},
        {"ior", {{"surface", {{"material", {{"refractive", 1.0}}}}}}, "surface.material.refractive: ", "> 1"},
        {"lens thickness",
         {{"surface", {{"material", {{"refractive", 1.5}, {"thickness", 0.004}}}}}},
         "surface.material.thickness: ",
         "back face"},
        {"lens rim negative",
         {{"surface", {{"material", {{"refractive", 1.5}, {"thickness", 0.02}, {"rim", -0.001}}}}}},
         "surface.material.rim: ",
         "[0, 1]"},
        {"lens rim word",
         {{"surface", {{"material", {{"refractive", 1.5}, {"thickness", 0.02}, {"rim", "wide"}}}}}},
         "surface.material.rim: ",
         "\"auto\""},
        {"lens without ior",
         {{"surface", {{"material", {{"thickness", 0.02}}}}}},
         "surface.material.refractive: ",
         "missing required key"},
        {"bad material", {{"surface", {{"material", "glass"}}}}, "surface.material: ", "\"mirror\""},
        {"phong range", {{"surface", {{"phong_alpha", 1.5}}}}, "surface.phong_alpha: ", "[0, 1]"},
        {"initial not pfm", {{"surface", {{"initial", "h.png"}}}}, "surface.initial: ", ".pfm"},
        {"initial number", {{"surface", {{"initial", 3}}}}, "surface.initial: ", "flat"},
        {"paraboloid focal",
         {{"surface", {{"initial", {{"paraboloid", {{"focal_length", -1}}}}}}}},
         "surface.initial.paraboloid.focal_length: ",
         "> 0"},
        {"target empty", {{"target", json::object()}}, "target: ", "needs"},
        {"target both", {{"target", {{"text", "E"}, {"image", "E.png"}}}}, "target: ", "not both"},
        {"target empty text", {{"target", {{"text", ""}}}}, "target.text: ", "empty"},
        {"target margin", {{"target", {{"text", "E"}, {"margin", 0.45}}}}, "target.margin: ", "[0, 0.45)"},
        {"font with image", {{"target", {{"image", "E.png"}, {"font", "X"}}}}, "target.font: ", "text target"},
        {"empty image path", {{"target", {{"image", ""}}}}, "target.image: ", "empty"},
        {"bad upsample", {{"target", {{"image", "E.png"}, {"upsample", "cubic"}}}}, "target.upsample: ", "\"box\""},
        {"upsample with text", {{"target", {{"text", "E"}, {"upsample", "box"}}}}, "target.upsample: ", "image target"},
        {"bad fit", {{"target", {{"image", "E.png"}, {"fit", "fill"}}}}, "target.fit: ", "\"contain\""},
        {"fit with text", {{"target", {{"text", "E"}, {"fit", "cover"}}}}, "target.fit: ", "image target"},
        {"meshes not array", {{"meshes", {{"file", "a.obj"}}}}, "meshes: ", "expected an array"},
        {"mesh entry not object", {{"meshes", {1}}}, "meshes[0]: ", "expected an object"},
        {"mesh without file", {{"meshes", {{{"material", "mirror"}}}}}, "meshes[0].file: ", "missing required key"},
        {"mesh material",
         {{"meshes", {{{"file", "a.obj"}, {"material", "glass"}}}}},
         "meshes[0].material: ",
         R"("absorber", "mirror" or {"refractive": ior})"},
        {"mesh index not above 1",
         {{"meshes", {{{"file", "a.obj"}, {"material", {{"refractive", 1.0}}}}}}},
         "meshes[0].material.refractive: ",
         "must be > 1"},
        {"mesh index missing", {{"meshes", {{{"file", "a.obj"}, {"material", json::object()}}}}},
         "meshes[0].material.refractive: ",
         "missing required key"},
        {"mesh thickness",
         {{"meshes", {{{"file", "a.obj"}, {"material", {{"refractive", 1.5}, {"thickness", 0.01}}}}}}},
         "meshes[0].material.thickness: ",
         "closed solid"},
        {"meshes need embree",
         {{"meshes", {{{"file", "a.obj"}}}}, {"trace", {{"tracer", "heightfield"}}}},
         "trace.tracer: ",
         "embree"},
        {"name type", {{"name", 5}}, "name: ", "expected a string"},
        {"receiver facing away", {{"receiver", {{"normal", {0, 0, 1}}}}}, "receiver.normal: ", "faces away"},
        {"receiver behind a lens's back face",
         {{"surface", {{"material", {{"refractive", 1.5}, {"thickness", 0.02}}}}},
          {"receiver", {{"center", {0, 0, -0.5}}, {"normal", {0, 0, -1}}}}},
         "receiver.normal: ",
         "faces away"},
    };
    for (const auto& c : cases) {
        const std::string what = c.what;
        CAPTURE(what);
        json j = minimal_scene();
        j.merge_patch(c.patch);
        const std::string msg = parse_error(j);
        CAPTURE(msg);
        CHECK(starts_with(msg, c.expected_prefix));
        CHECK(msg.find(c.expected_text) != std::string::npos);
    }

    // Top-level garbage.
    for (const json& garbage : {json(nullptr), json(3), json("scene"), json::array({1, 2})}) {
        const std::string msg = parse_error(garbage);
        CAPTURE(msg);
        CHECK(starts_with(msg, "scene: expected an object"));
    }
}

TEST_CASE("a receiver is refused only when no point of the surface lies in front of it") {
    json j = minimal_scene();
    // Edge-on through the surface's centre: half the surface is in front of its plane.
    j["receiver"]["normal"] = {1, 0, 0};
    CHECK(parse_error(j).empty());
    // Beyond the surface's edge (0.05 m from the centre) along +x, facing +x: all behind.
    j["receiver"]["center"] = {0.06, 0, 0};
    CHECK(starts_with(parse_error(j), "receiver.normal: "));
    // Inside the edge: the last 1 cm of the surface is in front.
    j["receiver"]["center"] = {0.04, 0, 0};
    CHECK(parse_error(j).empty());
    // A lens's light leaves through its back face 2 cm down: a receiver facing up from
    // 1 cm below the surface plane still sees it.
    j = minimal_scene();
    j["surface"]["material"] = {{"refractive", 1.5}, {"thickness", 0.02}};
    j["surface"]["height_bounds"] = {-0.005, 0.005};
    j["receiver"] = {{"center", {0, 0, -0.01}}, {"normal", {0, 0, -1}}};
    CHECK(parse_error(j).empty());
    // Extra meshes could fold the light round to its front: not refused.
    j = minimal_scene();
    j["receiver"]["normal"] = {0, 0, 1};
    j["meshes"] = {{{"file", "walls.obj"}, {"material", "mirror"}}};
    CHECK(parse_error(j).empty());
}

TEST_CASE("values that merge_patch cannot express") {
    json j = minimal_scene();
    j["surface"]["size"] = nullptr;
    CHECK(starts_with(parse_error(j), "surface.size: expected an array of 2 numbers, got null"));
    j = minimal_scene();
    j["light"]["direction"] = json::array({0, 0, -1});
    j["light"]["direction"][2] = json::array();
    CHECK(starts_with(parse_error(j), "light.direction[2]: expected a number, got an empty array"));
    j = minimal_scene();
    j["optimise"]["seed"] = std::uint64_t(18446744073709551615ULL);
    CHECK(job_from_json(j).options.seed == 18446744073709551615ULL);
    j["optimise"]["max_iterations"] = std::uint64_t(18446744073709551615ULL);
    CHECK(starts_with(parse_error(j), "optimise.max_iterations: must be an integer >= 0"));
    j = minimal_scene();
    j["surface"]["mesh"] = {16.0, 1e1};  // integral floats are integers
    const Scene s = scene_from_json(j);
    CHECK(s.surface.nx == 16);
    CHECK(s.surface.ny == 10);
}

namespace {

// One random mutation somewhere in the document.
void mutate(json& root, std::mt19937_64& rng) {
    const auto pick = [&](std::size_t n) { return std::size_t(rng() % n); };
    const std::vector<json> pool = {nullptr,
                                    true,
                                    -1,
                                    0,
                                    1,
                                    2,
                                    1e308,
                                    -1e308,
                                    1e-300,
                                    0.5,
                                    std::numeric_limits<double>::quiet_NaN(),
                                    std::numeric_limits<double>::infinity(),
                                    std::int64_t(-9223372036854775807LL - 1),
                                    std::uint64_t(18446744073709551615ULL),
                                    "",
                                    "flat",
                                    "mirror",
                                    "x.pfm",
                                    "point",
                                    json::array(),
                                    json::object(),
                                    json::array({0, 0, 0}),
                                    json::array({1, 2}),
                                    json::array({json::array({0, 1}), json::array({90, 0})}),
                                    json{{"paraboloid", {{"focal_length", 0.3}}}},
                                    json{{"refractive", 1.3}},
                                    json{{"a", json::array({nullptr, json::object()})}}};
    // Walk down a random path.
    json* node = &root;
    while ((node->is_object() || node->is_array()) && !node->empty() && pick(4) != 0) {
        const std::size_t k = pick(node->size());
        auto it = node->begin();
        std::advance(it, std::ptrdiff_t(k));
        node = &*it;
    }
    switch (pick(5)) {
        case 0:
        case 1: *node = pool[pick(pool.size())]; break;
        case 2:  // delete a key or element
            if (node->is_object() && !node->empty()) {
                auto it = node->begin();
                std::advance(it, std::ptrdiff_t(pick(node->size())));
                const std::string key = it.key();
                node->erase(key);
            } else if (node->is_array() && !node->empty()) {
                node->erase(pick(node->size()));
            }
            break;
        case 3:  // add a key, known or not, or an element
            if (node->is_object()) {
                static const char* keys[] = {"type",   "position", "radius", "profile", "rays",  "size",
                                             "mesh",   "initial",  "text",   "image",   "seed",  "bogus",
                                             "normal", "up",       "center", "_c",      "margin"};
                (*node)[keys[pick(std::size(keys))]] = pool[pick(pool.size())];
            } else if (node->is_array()) {
                node->push_back(pool[pick(pool.size())]);
            }
            break;
        default:  // perturb a number
            if (node->is_number()) *node = node->get<double>() * (pick(2) ? -1.0 : 1e6);
            break;
    }
}

}  // namespace

TEST_CASE("randomly mutated scenes parse or throw InputError, never anything else") {
    std::mt19937_64 rng(20240611);
    const std::vector<json> seeds = {full_scene(), minimal_scene(),
                                     json::parse(R"({"light": {"type": "point", "position": [0, 0, 0.3],
                                        "profile": [[0, 1], [45, 0.5]]}, "surface": {"initial": "flat",
                                        "material": {"refractive": 1.49}}, "receiver": {},
                                        "target": {"image": "t.png"}})")};
    int parsed = 0, rejected = 0;
    for (int trial = 0; trial < 240; ++trial) {
        json j = seeds[std::size_t(trial) % seeds.size()];
        const int mutations = 1 + int(rng() % 3);
        for (int m = 0; m < mutations; ++m) mutate(j, rng);
        CAPTURE(trial);
        try {
            const DesignJob s = job_from_json(j, "/tmp/base");
            ++parsed;
            // Whatever parses must survive the round trip too.
            const json out = job_to_json(s);
            CHECK(job_to_json(job_from_json(out, "/elsewhere")) == out);
        } catch (const InputError& e) {
            ++rejected;
            CHECK(std::string(e.what()).size() > 0);
        } catch (const std::exception& e) {
            FAIL("unexpected exception type: " << e.what() << " for " << j.dump());
        }
    }
    // The mutations should exercise both outcomes.
    CHECK(parsed > 10);
    CHECK(rejected > 10);
}

// Each optimise key lands in the field of the module that uses it (design/options.hpp:
// the objective's weights, the penalties', the proposals', the schedule's, the export's),
// read as written and written back as read.
TEST_CASE("optimise keys: each reaches its module's option field") {
    struct Row {
        const char* key;
        json value;
        double (*field)(const DesignOptions&);
    };
    const Row rows[] = {
        {"sobel_weight", 0.3, [](const DesignOptions& o) { return o.objective.sobel; }},
        {"energy_threshold", 0.8, [](const DesignOptions& o) { return o.objective.energy_threshold; }},
        {"lost_light_weight", 2.5, [](const DesignOptions& o) { return o.objective.lost_light; }},
        {"height_bound_weight", 3.0, [](const DesignOptions& o) { return o.penalties.height_bound; }},
        {"valley_weight", 4.0, [](const DesignOptions& o) { return o.penalties.valley; }},
        {"valley_min_angle", 160.0, [](const DesignOptions& o) { return o.penalties.valley_min_angle; }},
        {"smoothness_weight", 5.0, [](const DesignOptions& o) { return o.penalties.smoothness; }},
        {"bandit_sync", 7, [](const DesignOptions& o) { return double(o.proposals.bandit_sync); }},
        {"preprocess_iterations", 11, [](const DesignOptions& o) { return double(o.proposals.preprocess_iterations); }},
        {"preprocess_keep", 2, [](const DesignOptions& o) { return double(o.proposals.preprocess_keep); }},
        {"error_guided", true, [](const DesignOptions& o) { return double(o.proposals.error_guided); }},
        {"single_vertex", true, [](const DesignOptions& o) { return double(o.proposals.single_vertex); }},
        {"max_shift_cells", 6.0, [](const DesignOptions& o) { return o.proposals.max_shift_cells; }},
        {"min_shift_cells", 0.5, [](const DesignOptions& o) { return o.proposals.min_shift_cells; }},
        {"refine_max_shift_cells", 2.0, [](const DesignOptions& o) { return o.proposals.refine_max_shift_cells; }},
        {"initial_acceptance", 0.2, [](const DesignOptions& o) { return o.schedule.initial_acceptance; }},
        {"refine_initial_acceptance", 0.01, [](const DesignOptions& o) { return o.schedule.refine_initial_acceptance; }},
        {"initial_temperature_scale", 3.0, [](const DesignOptions& o) { return o.schedule.initial_temperature_scale; }},
        {"cooling", 0.9, [](const DesignOptions& o) { return o.schedule.cooling; }},
        {"temperature_steps", 60, [](const DesignOptions& o) { return double(o.schedule.temperature_steps); }},
        {"reheat_factor", 0.25, [](const DesignOptions& o) { return o.schedule.reheat_factor; }},
        {"patience_fraction", 0.2, [](const DesignOptions& o) { return o.schedule.patience_fraction; }},
        {"export_subdivisions", 3, [](const DesignOptions& o) { return double(o.exports.subdivisions); }},
        {"export_tolerance", 0.1, [](const DesignOptions& o) { return o.exports.tolerance; }},
        {"export_max_triangles", 5000, [](const DesignOptions& o) { return double(o.exports.max_triangles); }},
        {"smooth_iterations", 2, [](const DesignOptions& o) { return double(o.smooth_iterations); }},
        {"keep_better_start", false, [](const DesignOptions& o) { return double(o.keep_better_start); }},
        {"coarse_rays_per_cell", 9.0, [](const DesignOptions& o) { return o.coarse_rays_per_cell; }},
        {"min_rays_per_mesh_cell", 48.0, [](const DesignOptions& o) { return o.min_rays_per_mesh_cell; }},
    };
    const DesignOptions defaults;
    for (const Row& r : rows) {
        CAPTURE(r.key);
        json j = minimal_scene();
        j["optimise"][r.key] = r.value;
        const DesignJob job = job_from_json(j);
        const double expected = r.value.is_boolean() ? double(r.value.get<bool>()) : r.value.get<double>();
        CHECK(r.field(job.options) == expected);
        CHECK(r.field(defaults) != expected);  // the value read is not the default (else the row proves nothing)
        CHECK(job_to_json(job)["optimise"][r.key] == r.value);
    }
    json j = minimal_scene();
    j["optimise"]["bandit"] = "ucb1";
    j["optimise"]["kernel_shapes"] = "isotropic";
    j["optimise"]["evaluation"] = "full";
    j["optimise"]["export_formats"] = json::array({"sag"});
    j["optimise"]["export_spline"] = "least_squares";
    const DesignOptions o = job_from_json(j).options;
    CHECK(o.exports.spline == SplineForm::least_squares);
    CHECK(DesignOptions{}.exports.spline == SplineForm::automatic);
    CHECK(job_to_json(job_from_json(j))["optimise"]["export_spline"] == "least_squares");
    CHECK(o.proposals.bandit == BanditKind::ucb1);
    CHECK(o.proposals.kernel_shapes == KernelShapes::isotropic);
    CHECK(o.evaluation == EvaluationMode::full);
    CHECK(o.exports.formats == std::vector<ExportFormat>{ExportFormat::sag});
    // The scene alone carries none of them: scene_to_json writes no optimise block.
    CHECK_FALSE(scene_to_json(job_from_json(j).scene).contains("optimise"));
}

TEST_CASE("scene_to_json writes every default and reads back to the same JSON") {
    const std::vector<json> scenes = {
        minimal_scene(), full_scene(),
        json::parse(R"({"light": {"type": "point", "position": [0.01, 0, 0.3], "profile": [[0, 1], [80, 0.25]]},
                        "surface": {"normal": [0, -0.5, 1], "up": [0.3, 1, 0.2], "initial": "h.pfm"},
                        "receiver": {"center": [0.1, 0.2, 0.6], "normal": [0.1, 0.1, -1]},
                        "target": {"image": "E.png", "fit": "cover"}})"),
        json::parse(R"({"light": {"type": "disk", "center": [0, 0, 0.3], "normal": [0, 0.2, -1], "radius": 0.004,
                                  "rays": 77}, "surface": {}, "receiver": {}, "target": {"text": "E"}})")};
    for (const json& j : scenes) {
        const DesignJob job = job_from_json(j, "/some/dir");
        const Scene& s = job.scene;
        const json out = job_to_json(job);
        CAPTURE(out.dump());
        CHECK(job_to_json(job_from_json(out, "/other")) == out);
        // And through text, as metrics.json would be read back.
        CHECK(job_to_json(job_from_json(json::parse(out.dump()))) == out);
        // The scene alone: the same, without the optimiser's block.
        json scene_only = out;
        scene_only.erase("optimise");
        CHECK(scene_to_json(s) == scene_only);
        // Defaults are written out.
        CHECK(out["surface"].contains("phong_alpha"));
        CHECK(out["receiver"].contains("deposit"));
        CHECK(out["trace"]["max_depth"] == s.trace.max_depth);
        CHECK(out["optimise"]["seed"] == job.options.seed);
        CHECK(out["light"]["rays_per_cell"] == s.light.rays_per_cell);
    }
    // A lens's rim: "auto" is written as such, metres as given.
    CHECK(scene_to_json(scene_from_json(full_scene()))["surface"]["material"]["rim"] == "auto");
    json with_rim = full_scene();
    with_rim["surface"]["material"]["rim"] = 0.003;
    CHECK(std::get<Lens>(scene_from_json(with_rim).surface.material).rim == 0.003);
    CHECK(scene_to_json(scene_from_json(with_rim))["surface"]["material"]["rim"] == 0.003);
    // The default point-light axis is written as the direction to the surface centre.
    const json out = scene_to_json(scene_from_json(scenes[2]));
    CHECK(out["light"]["axis"] == json::array({-0.01, 0.0, -0.3}));
    CHECK(out["surface"]["initial"] == "h.pfm");
    CHECK(scene_to_json(scene_from_json(scenes[1], "/d"))["meshes"][0]["file"] == "/d/walls.obj");
}

TEST_CASE("load_scene reports files, syntax errors and keys") {
    const TempDir dir;

    SUBCASE("missing file") {
        const fs::path p = dir.path / "nope.json";
        try {
            (void)io::load_scene(p);
            FAIL("no exception");
        } catch (const IoError& e) {
            CHECK(std::string(e.what()).find(p.string()) != std::string::npos);
        }
    }
    SUBCASE("syntax error names file, line and column") {
        const fs::path p = dir.write("bad.json", "{\n  \"light\": {\"type\": \"collimated\"},\n  \"surface\": {,\n}");
        try {
            (void)io::load_scene(p);
            FAIL("no exception");
        } catch (const IoError&) {
            FAIL("a syntax error is not an I/O error");
        } catch (const InputError& e) {
            const std::string msg = e.what();
            CAPTURE(msg);
            CHECK(starts_with(msg, p.string() + ": invalid JSON at line 3, column 15"));
            CHECK(msg.find("byte") != std::string::npos);
        }
    }
    SUBCASE("overflowing number") {
        const fs::path p = dir.write("inf.json", R"({"light": {"type": "collimated"}, "surface": {"size": [1e999, 1]},
                                                     "receiver": {}})");
        CHECK_THROWS_AS((void)io::load_scene(p), InputError);
        try {
            (void)io::load_scene(p);
        } catch (const InputError& e) {
            CHECK(std::string(e.what()).find("1e999") != std::string::npos);
            CHECK(starts_with(e.what(), p.string()));
        }
    }
    SUBCASE("duplicate key") {
        const fs::path p = dir.write("dup.json", R"({"light": {"type": "collimated"}, "surface": {},
            "receiver": {"size": [0.1, 0.1], "resolution": [10, 10], "size": [0.2, 0.2]}})");
        try {
            (void)io::load_scene(p);
            FAIL("no exception");
        } catch (const InputError& e) {
            CHECK(std::string(e.what()) ==
                  p.string() + ": receiver.size: duplicate key (a key may appear only once in an object)");
        }
        // The same key in different objects, and in objects inside arrays, is fine.
        const fs::path ok = dir.write("ok.json", R"({"light": {"type": "collimated"}, "surface": {"size": [0.1, 0.1]},
            "receiver": {"size": [0.1, 0.1]}, "meshes": [{"file": "m.obj"}, {"file": "m.obj"}]})");
        dir.write("m.obj", "v 0 0 0\n");
        CHECK(io::load_scene(ok).meshes.size() == 2);
        const fs::path dup2 = dir.write("dup2.json", R"({"light": {"type": "collimated"}, "surface": {},
            "receiver": {}, "meshes": [{"file": "m.obj"}, {"file": "m.obj", "file": "m.obj"}]})");
        CHECK_THROWS_WITH_AS((void)io::load_scene(dup2), doctest::Contains("meshes[1].file: duplicate key"),
                             InputError);
    }
    SUBCASE("validation errors name the file and the key") {
        const fs::path p = dir.write("neg.json", R"({"light": {"type": "collimated"}, "surface": {"size": [0.1, -0.1]},
                                                     "receiver": {}})");
        CHECK_THROWS_WITH_AS((void)io::load_scene(p), (p.string() + ": surface.size[1]: must be > 0, got -0.1").c_str(),
                             InputError);
    }
    SUBCASE("comments are allowed") {
        const fs::path p = dir.write("c.json",
                                     "// a scene\n{\"light\": {\"type\": \"collimated\"}, /* x */ "
                                     "\"surface\": {}, \"receiver\": {}}");
        CHECK(io::load_scene(p).receiver.width == 200);
    }
    SUBCASE("files named by the scene resolve against its directory and must exist") {
        fs::create_directories(dir.path / "sub");
        const fs::path p = dir.write("sub/s.json", R"({"light": {"type": "collimated"}, "receiver": {},
            "surface": {"initial": "h.pfm"}, "target": {"image": "../E.png"}})");
        try {
            (void)io::load_scene(p);
            FAIL("no exception");
        } catch (const IoError& e) {
            const std::string msg = e.what();
            CAPTURE(msg);
            CHECK(msg.find("surface.initial: file not found") != std::string::npos);
            CHECK(msg.find((dir.path / "sub" / "h.pfm").string()) != std::string::npos);
        }
        ImageF img(2, 2);
        img.setZero();
        io::write_pfm(dir.path / "sub" / "h.pfm", img);
        CHECK_THROWS_WITH_AS((void)io::load_scene(p), doctest::Contains("target.image: file not found"), IoError);
        dir.write("E.png", "not really a png; existence is all that is checked here");
        const Scene s = io::load_scene(p);
        CHECK(s.base_dir == fs::absolute(dir.path / "sub").lexically_normal());
        CHECK(s.surface.initial_pfm == (s.base_dir / "h.pfm"));
        CHECK(s.target->image == fs::absolute(dir.path / "E.png").lexically_normal());
        // Re-resolving against base_dir is harmless: the stored names are absolute.
        CHECK(s.base_dir / s.target->image == s.target->image);

        const fs::path m = dir.write("sub/m.json", R"({"light": {"type": "collimated"}, "receiver": {},
            "surface": {}, "meshes": [{"file": "gone.obj"}]})");
        CHECK_THROWS_WITH_AS((void)io::load_scene(m), doctest::Contains("meshes[0].file: file not found"), IoError);
        fs::create_directories(dir.path / "sub" / "d.pfm");
        const fs::path d = dir.write("sub/d.json", R"({"light": {"type": "collimated"}, "receiver": {},
            "surface": {"initial": "d.pfm"}})");
        CHECK_THROWS_WITH_AS((void)io::load_scene(d), doctest::Contains("surface.initial: not a regular file"),
                             IoError);
    }
}

TEST_CASE("randomly corrupted scene files load or throw InputError, never anything else") {
    const TempDir dir;
    const std::string text = full_scene().dump(1);
    std::mt19937_64 rng(7);
    const std::string junk = "{}[],:\"\\/ 0123456789.eE+-truefalsnul\n\x01\xff";
    int loaded = 0;
    for (int trial = 0; trial < 120; ++trial) {
        std::string t = text;
        const int edits = 1 + int(rng() % 4);
        for (int e = 0; e < edits; ++e) {
            const std::size_t at = std::size_t(rng() % t.size());
            switch (rng() % 3) {
                case 0: t[at] = junk[rng() % junk.size()]; break;
                case 1: t.erase(at, 1 + rng() % 8); break;
                default: t.insert(at, 1, junk[rng() % junk.size()]); break;
            }
            // push_back, not t = "{": GCC 12 at -O3 warns -Wrestrict on assigning a one-character
            // literal to a std::string (a false positive, https://gcc.gnu.org/PR105329).
            if (t.empty()) t.push_back('{');
        }
        const fs::path p = dir.write("fuzz.json", t);
        CAPTURE(t);
        try {
            (void)io::load_scene(p);
            ++loaded;  // only if the edits happened to keep it valid (walls.obj is missing, so rarely)
        } catch (const InputError& e) {
            CHECK(starts_with(e.what(), p.string() + ": "));
        } catch (const std::exception& e) {
            FAIL("unexpected exception type: " << e.what());
        }
    }
    CHECK(loaded == 0);  // the file names walls.obj, which does not exist
}

TEST_CASE("the example scenes load") {
#ifdef FREEFORM_SOURCE_DIR
    const fs::path dir = fs::path(FREEFORM_SOURCE_DIR) / "examples" / "scenes";
#else
    const fs::path dir = fs::path(__FILE__).parent_path().parent_path() / "examples" / "scenes";
#endif
    REQUIRE(fs::is_directory(dir));
    int count = 0;
    for (const auto& entry : fs::directory_iterator(dir)) {
        if (entry.path().extension() != ".json") continue;
        CAPTURE(entry.path().string());
        const DesignJob job = io::load_job(entry.path());
        CHECK_FALSE(job.scene.name.empty());
        CHECK(job_to_json(job_from_json(job_to_json(job))) == job_to_json(job));
        ++count;
    }
    CHECK(count >= 4);
    const Scene lens = io::load_scene(dir / "lens.json");
    CHECK(std::get<Lens>(lens.surface.material).ior == 1.49);
    CHECK(lens.receiver.frame.w == Vec3d{0, 0, 1});
    const Scene point = io::load_scene(dir / "point-light.json");
    CHECK(point.surface.aperture == Aperture::ellipse);
    CHECK(point.target->text == "F");
    const Scene para = io::load_scene(dir / "demo-paraboloid.json");
    CHECK(para.surface.initial_paraboloid->focal_length == 0.5);
    CHECK_FALSE(para.target.has_value());
}

TEST_CASE("make_initial_heightmap") {
    json j = minimal_scene();
    j["surface"]["size"] = {0.1, 0.06};
    j["surface"]["height_bounds"] = {-0.001, 0.0005};

    SUBCASE("flat") {
        const Heightmap h = io::make_initial_heightmap(scene_from_json(j), 11, 7);
        CHECK(h.nx() == 11);
        CHECK(h.ny() == 7);
        for (float v : h.heights()) CHECK(v == 0.0f);
        for (const Vec3& n : h.normals()) CHECK(n == Vec3{0, 0, 1});
    }
    SUBCASE("flat outside the bounds is clamped") {
        j["surface"]["height_bounds"] = {0.001, 0.002};
        const Heightmap h = io::make_initial_heightmap(scene_from_json(j), 5, 5);
        for (float v : h.heights()) CHECK(v == 0.001f);
    }
    SUBCASE("paraboloid") {
        const double f = 0.5;
        j["surface"]["initial"] = {{"paraboloid", {{"focal_length", f}}}};
        const Heightmap h = io::make_initial_heightmap(scene_from_json(j), 21, 13);
        int clamped = 0;
        for (int jj = 0; jj < 13; ++jj)
            for (int i = 0; i < 21; ++i) {
                const double u = (i / 20.0 - 0.5) * 0.1, v = (jj / 12.0 - 0.5) * 0.06;
                const double expected = (u * u + v * v) / (4 * f);
                if (expected > 0.0005) ++clamped;
                CHECK(std::abs(h(i, jj) - std::min(expected, 0.0005)) < 1e-7);
            }
        CHECK(clamped > 0);  // the corners reach the upper bound
        CHECK(h(10, 6) == 0.0f);
    }
    SUBCASE("from a PFM file, top image row = +v edge, resampled when sizes differ") {
        const TempDir dir;
        // Heights that vary along both axes: h = 1e-4 * (c + 10 r') with r' counted from the bottom.
        const int cols = 5, rows = 3;
        ImageF img(rows, cols);
        for (int r = 0; r < rows; ++r)
            for (int c = 0; c < cols; ++c) img(r, c) = float(1e-5 * (c + 10 * (rows - 1 - r)));
        io::write_pfm(dir.path / "h.pfm", img);
        j["surface"]["initial"] = "h.pfm";
        const Scene s = scene_from_json(j, dir.path);

        const Heightmap same = io::make_initial_heightmap(s, cols, rows);
        for (int jj = 0; jj < rows; ++jj)
            for (int i = 0; i < cols; ++i) CHECK(same(i, jj) == float(1e-5 * (i + 10 * jj)));

        // Bilinear resampling of a bilinear function is exact (up to float rounding).
        const Heightmap fine = io::make_initial_heightmap(s, 9, 5);
        for (int jj = 0; jj < 5; ++jj)
            for (int i = 0; i < 9; ++i) CHECK(std::abs(fine(i, jj) - 1e-5 * (i / 2.0 + 10 * jj / 2.0)) < 1e-9);
        CHECK(fine.size().x == 0.1);

        // Values beyond the bounds are clamped.
        img(0, 0) = 1.0f;
        io::write_pfm(dir.path / "h.pfm", img);
        CHECK(io::make_initial_heightmap(s, cols, rows)(0, rows - 1) == 0.0005f);

        // A 1-pixel-wide file cannot be a surface.
        io::write_pfm(dir.path / "h.pfm", ImageF::Zero(3, 1));
        CHECK_THROWS_WITH_AS((void)io::make_initial_heightmap(s, cols, rows),
                             doctest::Contains("surface.initial: heightmap"), InputError);

        // A missing file names the key and the path.
        fs::remove(dir.path / "h.pfm");
        CHECK_THROWS_WITH_AS((void)io::make_initial_heightmap(s, cols, rows), doctest::Contains("surface.initial"),
                             IoError);
    }
    SUBCASE("non-finite PFM values are rejected naming the file") {
        const TempDir dir;
        // write_pfm refuses NaN, so write the file by hand.
        std::string bytes = "Pf\n2 2\n-1.0\n";
        const float values[4] = {0.0f, std::numeric_limits<float>::quiet_NaN(), 0.0f, 0.0f};
        bytes.append(reinterpret_cast<const char*>(values), sizeof values);
        dir.write("nan.pfm", bytes);
        j["surface"]["initial"] = "nan.pfm";
        const Scene s = scene_from_json(j, dir.path);
        CHECK_THROWS_WITH_AS((void)io::make_initial_heightmap(s, 4, 4), doctest::Contains("nan.pfm"), InputError);
    }
    SUBCASE("grid sizes below 2 are rejected") {
        CHECK_THROWS_AS((void)io::make_initial_heightmap(scene_from_json(j), 1, 5), InputError);
    }
}
