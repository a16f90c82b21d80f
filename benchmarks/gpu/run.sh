#!/usr/bin/env bash
# The GPU checks and the GPU/CPU tracing comparison, in one prepared script for a machine
# with nvcc and a CUDA device (docs/cuda.md, "Measuring on a GPU"). It builds nothing with
# the project's CMake (the lent machine has none of its packages): nvcc and g++ are called
# directly on the headers, with Eigen, nlohmann-json, stb and the DejaVu font from
# .gpu-deps/ (made on a Debian machine by benchmarks/gpu/carry.sh) or from /usr/include.
#
#   benchmarks/gpu/run.sh [OUT_DIR]     (default: $OUT where the device tool sets it,
#                                        else benchmarks/results/gpu)
#
# 1. tests/cuda/run.cmake MODE=run: the GPU tracer against the CPU one, bit for bit
#    (the ctest cuda_gpu_vs_cpu).
# 2. trace_bench on the letter E's final level and on a 512² photograph (the camera
#    example's target at 512²): full traces on 2 CPU threads, on every CPU thread and on
#    the GPU, and one move's retrace; histograms and records compared bit for bit.
# 3. design_bench (benchmarks/gpu/design_bench.cpp with the command line's device,
#    apps/freeform/device/cuda.cu): the letter E designed for a fixed 20,000 iterations
#    on 2 CPU threads and with its windows on the GPU (speeds; heights bit for bit), then
#    for 40 s on the CPU and 10 s on the GPU (cell-mean errors of the designed surfaces). DESIGN_BENCH=0 skips it.
# Writes OUT_DIR/gpu_vs_cpu.log, OUT_DIR/trace_bench.json, OUT_DIR/trace_bench.log,
# OUT_DIR/design_bench.json and OUT_DIR/design_bench.log.
# About 3 minutes on an H200 machine (16 cores) for steps 1 and 2, most of it compiling;
# step 3 about 3 more (not yet run on a device).
set -euo pipefail
root=$(cd "$(dirname "$0")/../.." && pwd)
out=${1:-${OUT:-$root/benchmarks/results/gpu}}
mkdir -p "$out"
nvcc=${NVCC:-$(command -v nvcc || echo /usr/local/cuda/bin/nvcc)}
[ -x "$nvcc" ] || { echo "run.sh: no nvcc (set NVCC)" >&2; exit 2; }
deps="$root/.gpu-deps"
if [ -d "$deps/include" ]; then
    inc=("$deps/include")
    # The letter E's target is rendered with DejaVu Sans Bold (freeform/io/font.hpp looks in ~/.fonts).
    [ -d /usr/share/fonts/truetype/dejavu ] || { mkdir -p "$HOME/.fonts" && cp "$deps"/fonts/*.ttf "$HOME/.fonts/"; }
else
    inc=(/usr/include/eigen3 /usr/include/stb)  # nlohmann/ is in /usr/include
fi
isystem=()
for d in "${inc[@]}"; do isystem+=(-isystem "$d"); done
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
nvidia-smi -L | tee "$out/device.txt" || true

echo "== 1. GPU == CPU (tests/cuda/run.cmake MODE=run)"
joined=$(IFS='|'; echo "$root/include|${inc[*]}")
set -o pipefail
cmake -DMODE=run -DNVCC="$nvcc" -DHOST_COMPILER=g++ -DEXTRA_FLAGS= \
    -DOUTPUT="$work/cuda/kernels_check.o" \
    -DGPU_SOURCE="$root/tests/cuda/gpu_vs_cpu.cu" -DGPU_HOST_SOURCE="$root/tests/cuda/gpu_vs_cpu_host.cpp" \
    -DINCLUDE_DIRS="$joined" -P "$root/tests/cuda/run.cmake" 2>&1 | tee "$out/gpu_vs_cpu.log"
if grep -q "freeform-cuda-check: skipped" "$out/gpu_vs_cpu.log"; then
    echo "run.sh: no CUDA device here: step 1 skipped, step 2 gives CPU figures only"
elif ! grep -q "freeform-cuda-check: passed" "$out/gpu_vs_cpu.log"; then
    echo "run.sh: the GPU == CPU test did not pass" >&2
    exit 1
fi

echo "== 2. trace_bench"
src="$root/benchmarks/gpu"
flags=(-std=c++20 -O3 -I"$root/include" "${isystem[@]}")
g++ "${flags[@]}" -ffp-contract=off -fopenmp -c "$src/trace_bench_host.cpp" -o "$work/host.o" &
host=$!
g++ -std=c++20 -O2 "${isystem[@]}" -c "$src/stb_impl.cpp" -o "$work/stb.o" &
stb=$!
"$nvcc" "${flags[@]}" --extended-lambda --fmad=false -arch=native -diag-suppress 20012,20015 -ccbin g++ \
    -x cu -c "$src/trace_bench.cu" \
    -o "$work/bench.o"
wait "$host"
wait "$stb"
"$nvcc" -ccbin g++ -Xcompiler -fopenmp "$work/bench.o" "$work/host.o" "$work/stb.o" -o "$work/trace_bench"
(cd "$root" && "$work/trace_bench" "$out/trace_bench.json" --repeats 5 examples/scenes/letter-e.json \
    examples/scenes/camera.json@512) 2>&1 | tee "$out/trace_bench.log"
if [ "${DESIGN_BENCH:-1}" != 0 ]; then
    echo "== 3. design_bench"
    g++ "${flags[@]}" -O2 -ffp-contract=off -fopenmp -c "$root/benchmarks/gpu/design_bench.cpp" \
        -o "$work/design_host.o" &
    host=$!
    "$nvcc" "${flags[@]}" --extended-lambda --fmad=false -arch=native -diag-suppress 20012,20015 -ccbin g++ \
        -x cu -c "$root/apps/freeform/device/cuda.cu" -o "$work/device.o"
    wait "$host"
    "$nvcc" -ccbin g++ -Xcompiler -fopenmp "$work/design_host.o" "$work/device.o" "$work/stb.o" \
        -o "$work/design_bench"
    (cd "$root" && "$work/design_bench" "$out/design_bench.json" examples/scenes/letter-e.json --iterations 20000 \
        --threads 2 --gpu-seconds 10 --cpu-seconds 40) 2>&1 | tee "$out/design_bench.log"
fi
echo "run.sh: results in $out"
