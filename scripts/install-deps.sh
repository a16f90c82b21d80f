#!/usr/bin/env bash
# Installs the Debian 12 packages freeform needs, and only those that are missing.
#   scripts/install-deps.sh          build, test and demo dependencies (the Python module's included)
#   scripts/install-deps.sh bench    also the optimisers the benchmark studies compare against
#   scripts/install-deps.sh clang    also Debian's clang (make test-clang; libomp-dev is in the base list)
#   scripts/install-deps.sh validate also POV-Ray 3.7 and numpy (make validate: independent check of the tracer)
# Silent when everything is already installed; safe to run any number of times.
set -euo pipefail

packages=(
    make cmake ninja-build g++
    libeigen3-dev libembree-dev doctest-dev libstb-dev libcli11-dev nlohmann-json3-dev
    libbenchmark-dev libomp-dev
    libopenmpi-dev openmpi-bin
    libocct-data-exchange-dev libocct-modeling-algorithms-dev libocct-modeling-data-dev libocct-foundation-dev
    fonts-dejavu-core python3 python3-matplotlib
    pybind11-dev python3-dev python3-numpy python3-pytest
)
for arg in "$@"; do
    case "$arg" in
        bench) packages+=(libpagmo-dev libnlopt-cxx-dev) ;;
        clang) packages+=(clang) ;;
        validate) packages+=(povray python3-numpy) ;;
        -h | --help)
            sed -n '2,7p' "$0" | sed 's/^# \{0,1\}//'
            exit 0
            ;;
        *)
            echo "install-deps.sh: unknown argument '$arg' (expected: bench, clang, validate)" >&2
            exit 2
            ;;
    esac
done

missing=()
for p in "${packages[@]}"; do
    status=$(dpkg-query -W -f='${db:Status-Status}' "$p" 2>/dev/null || true)
    if [[ "$status" != "installed" ]]; then
        missing+=("$p")
    fi
done
if [[ ${#missing[@]} -eq 0 ]]; then
    exit 0
fi

if [[ $(id -u) -eq 0 ]]; then
    as_root=()
elif command -v sudo >/dev/null 2>&1; then
    as_root=(sudo)
else
    echo "install-deps.sh: missing packages: ${missing[*]}; run as root or install sudo" >&2
    exit 1
fi

echo "install-deps.sh: installing ${missing[*]}"
export DEBIAN_FRONTEND=noninteractive
"${as_root[@]}" env DEBIAN_FRONTEND=noninteractive apt-get update -q
"${as_root[@]}" env DEBIAN_FRONTEND=noninteractive apt-get install -y -q --no-install-recommends "${missing[@]}"
