#include <cstdio>

#include <freeform/freeform.hpp>

// Designs a scene (the letter E by default), writes the part to mill and its figure.
int main(int argc, char** argv) {
    const char* file = argc > 1 ? argv[1] : "examples/scenes/letter-e.json";
    const freeform::DesignJob job = freeform::io::load_job(file);  // the scene and its "optimise" options
    const freeform::CompletedDesign d = freeform::design(job, freeform::io::load_target_image(job.scene));
    freeform::io::write_stl(argc > 2 ? argv[2] : "letter-e.stl", d.exported.fabrication.mesh);
    std::printf("error_physical %.4f, %zu triangles\n", d.error_physical().value_or(-1.0),
                d.exported.fabrication.mesh.triangles.size());
}
