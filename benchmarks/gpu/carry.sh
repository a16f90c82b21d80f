#!/usr/bin/env bash
# Gathers the header-only dependencies and the font that benchmarks/gpu/run.sh needs into
# .gpu-deps/ (ignored by git), on a Debian machine with the project's packages: a
# machine lent with a GPU has nvcc, CMake and g++ but no Debian packages. Then pass
# `.gpu-deps` in the device tool's `carry` (about 6 MB).
#
#   benchmarks/gpu/carry.sh
set -euo pipefail
root=$(cd "$(dirname "$0")/../.." && pwd)
deps="$root/.gpu-deps"
rm -rf "$deps"
mkdir -p "$deps/include" "$deps/fonts"
for dir in /usr/include/eigen3 /usr/include/nlohmann /usr/include/stb; do
    [ -d "$dir" ] || { echo "carry.sh: $dir is missing (apt-get install libeigen3-dev nlohmann-json3-dev libstb-dev)" >&2; exit 1; }
done
cp -r /usr/include/eigen3/Eigen /usr/include/eigen3/unsupported /usr/include/nlohmann "$deps/include/"
cp /usr/include/stb/stb_image.h /usr/include/stb/stb_image_write.h /usr/include/stb/stb_truetype.h "$deps/include/"
font=/usr/share/fonts/truetype/dejavu/DejaVuSans-Bold.ttf
[ -f "$font" ] || { echo "carry.sh: $font is missing (apt-get install fonts-dejavu-core)" >&2; exit 1; }
cp "$font" "$deps/fonts/"
du -sh "$deps"
