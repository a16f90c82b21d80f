#!/usr/bin/env bash
# The Phong alpha scan behind the default surface.phong_alpha = 1/2 (docs/export.md, "The
# simulated surface is the exported surface"): each case's transport start
# (`freeform design --start-only`) at several alphas; prints case, alpha, the design's
# error, the exported mesh's error and the subdivision k chosen for the export.
#   benchmarks/study/alpha_scan.sh [BIN]     (BIN: default build/release/bin/freeform)
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/../.."
bin=${1:-build/release/bin/freeform}
python=/usr/bin/python3
out=$(mktemp -d)
trap 'rm -rf "$out"; rm -f examples/scenes/.alpha-scan-*.json' EXIT
for c in letter-e lens point-light headlight; do
    for a in 0.25 0.4 0.5 0.6 0.75; do
        # Next to the original, so that its relative file names still resolve.
        scene=examples/scenes/.alpha-scan-$c-$a.json
        $python -c 'import json, sys
s = json.load(open(sys.argv[1])); s.setdefault("surface", {})["phong_alpha"] = float(sys.argv[2])
json.dump(s, open(sys.argv[3], "w"))' "examples/scenes/$c.json" "$a" "$scene"
        "$bin" design "$scene" --out "$out/$c-$a" --start-only --quiet >/dev/null
        $python -c 'import json, sys
m = json.load(open(sys.argv[1]))
print("%-12s alpha %-5s error %.4f exported %.4f k %d" % (sys.argv[2], sys.argv[3], m["error"], m["error_exported"], m["export"]["subdivisions"]))' \
            "$out/$c-$a/metrics.json" "$c" "$a"
    done
done
