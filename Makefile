# Entry points for people and CI. The real build is CMake (see CMakePresets.json).
#   make demo           install dependencies, build, run the demo (results in results/demo)
#   make test           release build + all tests
#   make test-clang     Release build with Debian's clang + tests (build/clang)
#   make test-sanitize  AddressSanitizer/UBSan build with Debian's clang + tests (CI's clang build)
#   make test-tsan      ThreadSanitizer build with Debian's clang: the threaded tests (task pool,
#                       annealer, incremental evaluation; build/tsan)
#   make fuzz [FUZZ_TIME=60] [FUZZ_JOBS=1]  libFuzzer + ASan/UBSan build with clang (build/fuzz),
#                       then each reader's fuzz target for FUZZ_TIME seconds; findings in
#                       build/fuzz/artifacts/<reader>/, non-zero exit if any (docs/fuzzing.md)
#   make bench [QUICK=1]  micro-benchmarks (JSON in benchmarks/results) + speed/accuracy study
#                         (benchmarks/results/REPORT.md; the full study takes about 1 h 50 min on
#                         2 cores and reuses the runs in benchmarks/results/runs (one .json.gz
#                         per run), the committed ones included; STUDY_ARGS=--fresh measures
#                         every run again)
#   make validate       independent check with POV-Ray 3.7 photon mapping: designs E, F, L, the
#                       headlight, E in sunlight, L with Fresnel losses, renders them in POV-Ray,
#                       compares (benchmarks/results/validation.md;
#                       VALIDATE_ARGS="--reuse DIR" reuses designs, see scripts/validate/validate.py -h)
# The presets set FREEFORM_WERROR=ON, so warnings are errors in every build made here and in
# CI; a plain `cmake -B build` leaves it OFF (warnings stay warnings for users' compilers).
JOBS ?= $(shell nproc)
BUILD := build/release
BIN := $(BUILD)/bin
# Debian's python3 carries python3-matplotlib; a python3 earlier on PATH (pyenv, venv) may not.
PYTHON ?= $(shell test -x /usr/bin/python3 && echo /usr/bin/python3 || echo python3)

# The demo: change these two lines to change what `make demo` runs and where it writes.
DEMO_OUT := results/demo
DEMO_CMD = $(BIN)/freeform design examples/scenes/letter-e.json --out $(DEMO_OUT) --time-budget 40

SOURCE_DIRS := include apps tests examples benchmarks
FORMAT_FILES = $(shell find $(SOURCE_DIRS) \( -name '*.hpp' -o -name '*.cpp' -o -name '*.cuh' -o -name '*.cu' \) -type f 2>/dev/null)

# Prerequisites run in order (deps before build) even under make -j; the build itself is parallel.
.NOTPARALLEL:

.PHONY: all deps deps-bench deps-clang deps-validate validate configure build demo test test-clang test-sanitize test-tsan fuzz bench clean format

all: build

deps:
	@scripts/install-deps.sh

deps-bench:
	@scripts/install-deps.sh bench

deps-clang:
	@scripts/install-deps.sh clang

deps-validate:
	@scripts/install-deps.sh validate

configure:
	cmake --preset release

build: configure
	cmake --build --preset release --parallel $(JOBS)

# The demo builds only the command line (the tests and benchmarks take minutes more).
demo: deps configure
	cmake --build --preset release --parallel $(JOBS) --target freeform_cli
	$(DEMO_CMD)
	@echo "demo results are in $(DEMO_OUT)/ (open comparison.png: target | result | difference)"

# Only the command line is needed (as for the demo).
VALIDATE_ARGS ?=
validate: deps deps-validate configure
	cmake --build --preset release --parallel $(JOBS) --target freeform_cli
	$(PYTHON) scripts/validate/validate.py --threads $(JOBS) $(VALIDATE_ARGS)

test: deps build
	ctest --preset release

# clang++ at -O3, no benchmarks (see the "clang" preset).
test-clang: deps deps-clang
	cmake --preset clang
	cmake --build --preset clang --parallel $(JOBS)
	ctest --preset clang

test-sanitize: deps deps-clang
	cmake --preset sanitize
	cmake --build --preset sanitize --parallel $(JOBS)
	ctest --preset sanitize

test-tsan: deps deps-clang
	cmake --preset tsan
	cmake --build --preset tsan --parallel $(JOBS)
	ctest --preset tsan

# The fuzz targets (tests/fuzz) run one after another by default; FUZZ_JOBS=2 runs two at
# a time. Each works on a scratch copy of its seed corpus (build/fuzz/corpus-work).
FUZZ_TIME ?= 60
FUZZ_JOBS ?= 1
FUZZ_READERS ?= scene image pfm obj stl cli

fuzz: deps deps-clang
	cmake --preset fuzz
	cmake --build --preset fuzz --parallel $(JOBS)
	tests/fuzz/run.sh build/fuzz $(FUZZ_TIME) $(FUZZ_JOBS) $(FUZZ_READERS)

# QUICK=1: shorter timing per micro-benchmark, results under benchmarks/results/quick/.
BENCH_OUT = benchmarks/results$(if $(QUICK),/quick)
BENCH_ARGS = $(if $(QUICK),--benchmark_min_time=0.1)
# Options for run_study.py, e.g. STUDY_ARGS="--fresh" or STUDY_ARGS="--seeds 3 --cases E,headlight".
STUDY_ARGS ?=

bench: deps deps-bench build
	@mkdir -p $(BENCH_OUT)
	@set -e; found=0; for exe in $(BIN)/bench_*; do \
		[ -x "$$exe" ] || continue; found=1; \
		name=$$(basename "$$exe"); name=$${name#bench_}; \
		echo "== $$exe -> $(BENCH_OUT)/$$name.json"; \
		"$$exe" $(BENCH_ARGS) --benchmark_out=$(BENCH_OUT)/$$name.json --benchmark_out_format=json; \
	done; [ $$found = 1 ] || echo "make bench: no bench_* programs in $(BIN)"
	$(PYTHON) benchmarks/micro/tables.py --trace $(BENCH_OUT)/trace.json --incremental $(BENCH_OUT)/incremental.json \
		> $(BENCH_OUT)/micro.md
	@echo "micro-benchmark tables: $(BENCH_OUT)/micro.md"
	@if [ -f benchmarks/study/run_study.py ]; then \
		echo "== $(PYTHON) benchmarks/study/run_study.py $(if $(QUICK),--quick) $(STUDY_ARGS)"; \
		$(PYTHON) benchmarks/study/run_study.py $(if $(QUICK),--quick) $(STUDY_ARGS); \
	else echo "make bench: benchmarks/study/run_study.py not found, study skipped"; fi
	@echo "benchmark results are in $(BENCH_OUT)/"

clean:
	rm -rf build

format:
	clang-format -i --style=file $(FORMAT_FILES)
