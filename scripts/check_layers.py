#!/usr/bin/env python3
"""Checks that the library's modules include only modules below them (docs/architecture.md §3).

Usage: scripts/check_layers.py [INCLUDE_DIR]   (default: include/freeform next to this script)
Exit 0 when every include of include/freeform/<module>/*.hpp names its own module or one
listed before it in ORDER; else prints each arrow that runs up and exits 1.
"""
import os
import re
import sys

# Bottom up: a module may include the ones before it (docs/architecture.md §3).
ORDER = ["core", "surface", "scene", "trace", "objective", "propose", "anneal", "transport", "design", "io",
         "cuda", "mpi"]
INCLUDE = re.compile(r'#\s*include\s+[<"](?:\.\./|freeform/)(\w+)/')


def upward_includes(root):
    rank = {m: i for i, m in enumerate(ORDER)}
    found = []
    for module in ORDER:
        folder = os.path.join(root, module)
        if not os.path.isdir(folder):
            continue
        for name in sorted(os.listdir(folder)):
            path = os.path.join(folder, name)
            with open(path, encoding="utf-8") as f:
                for number, line in enumerate(f, 1):
                    m = INCLUDE.match(line.strip())
                    if m and m.group(1) in rank and rank[m.group(1)] > rank[module]:
                        found.append("%s:%d: %s/ includes %s/ (above it): %s" % (
                            os.path.relpath(path, root), number, module, m.group(1), line.strip()))
    unknown = [d for d in sorted(os.listdir(root)) if os.path.isdir(os.path.join(root, d)) and d not in rank]
    found += ["%s/: a module missing from ORDER in scripts/check_layers.py" % d for d in unknown]
    return found


def main():
    here = os.path.dirname(os.path.abspath(__file__))
    root = sys.argv[1] if len(sys.argv) > 1 else os.path.join(here, "..", "include", "freeform")
    found = upward_includes(root)
    for line in found:
        print(line)
    print("check_layers: %d include(s) run up the layers" % len(found) if found else "check_layers: layers point down")
    return 1 if found else 0


if __name__ == "__main__":
    sys.exit(main())
