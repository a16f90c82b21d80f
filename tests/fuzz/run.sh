#!/usr/bin/env bash
# Runs the libFuzzer targets of a FREEFORM_FUZZ build (make fuzz; docs/fuzzing.md).
#   tests/fuzz/run.sh BUILD_DIR SECONDS JOBS READER...
# For each READER, BUILD_DIR/bin/fuzz_READER runs for SECONDS on a scratch copy of
# tests/fuzz/corpus/READER (BUILD_DIR/corpus-work/READER, so that the inputs it adds do
# not land in the repository) plus tests/fuzz/regressions/READER, with the dictionary
# tests/fuzz/dict/READER.dict when there is one. Findings go to
# BUILD_DIR/artifacts/READER/, the log to BUILD_DIR/logs/READER.log. JOBS targets run at
# a time. Exit status 1 when any target found something (or did not run).
set -uo pipefail

if [[ $# -lt 4 ]]; then
    sed -n '2,9p' "$0" | sed 's/^# \{0,1\}//' >&2
    exit 2
fi
build=$1 seconds=$2 jobs=$3
shift 3
here=$(cd "$(dirname "$0")" && pwd)

run_one() {
    local reader=$1
    local exe="$build/bin/fuzz_$reader"
    local work="$build/corpus-work/$reader" artifacts="$build/artifacts/$reader" log="$build/logs/$reader.log"
    mkdir -p "$work" "$artifacts" "$build/logs"
    touch "$build/logs/$reader.start"  # findings of this run are the artifacts newer than this
    if [[ ! -x "$exe" ]]; then
        echo "fuzz_$reader: $exe not built" > "$log"
        return 1
    fi
    # The scratch corpus keeps what earlier runs found; the seeds are copied over it.
    cp -f "$here/corpus/$reader"/* "$work"/ 2>/dev/null || true
    local options=(-max_total_time="$seconds" -rss_limit_mb=2048 -timeout=10 -close_fd_mask=3
                   -print_final_stats=1 -artifact_prefix="$artifacts/")
    [[ -f "$here/dict/$reader.dict" ]] && options+=(-dict="$here/dict/$reader.dict")
    "$exe" "${options[@]}" "$work" "$here/regressions/$reader" > "$log" 2>&1
}
export -f run_one
export build seconds here

printf '%s\n' "$@" | xargs -P "$jobs" -I{} bash -c 'run_one {}; echo "$?" > "$build/logs/{}.status"'

failed=()
printf '\n%-6s %8s %8s %10s %8s %s\n' target cov ft "exec/s" rss_mb result
for reader in "$@"; do
    log="$build/logs/$reader.log"
    status=$(cat "$build/logs/$reader.status" 2>/dev/null || echo 1)
    # The last progress line ("#N DONE cov: C ft: F ...", or the last pulse before a crash).
    last=$(grep -E '^#[0-9]+' "$log" 2>/dev/null | tail -n 1)
    cov=$(sed -nE 's/.* cov: ([0-9]+).*/\1/p' <<< "$last")
    ft=$(sed -nE 's/.* ft: ([0-9]+).*/\1/p' <<< "$last")
    execs=$(sed -nE 's/^stat::average_exec_per_sec: *([0-9]+).*/\1/p' "$log" 2>/dev/null)
    rss=$(sed -nE 's/^stat::peak_rss_mb: *([0-9]+).*/\1/p' "$log" 2>/dev/null)
    if [[ "$status" == 0 ]]; then
        result=ok
    else
        result="FINDING (exit $status): see $log and $build/artifacts/$reader/"
        failed+=("$reader")
    fi
    printf '%-6s %8s %8s %10s %8s %s\n' "$reader" "${cov:--}" "${ft:--}" "${execs:--}" "${rss:--}" "$result"
done
if [[ ${#failed[@]} -gt 0 ]]; then
    # A CI log may be all anyone sees of a finding: print the report and the input itself
    # (base64, for inputs up to 64 KiB) so that it can be rebuilt and replayed.
    for reader in "${failed[@]}"; do
        echo
        echo "---- fuzz_$reader: report ----"
        grep -m 1 -A 40 -E '^(==[0-9]+==|.*runtime error:|.*ERROR: libFuzzer)' "$build/logs/$reader.log" | head -n 40
        find "$build/artifacts/$reader" -type f -newer "$build/logs/$reader.start" | while read -r input; do
            echo "---- input $(basename "$input") ($(stat -c %s "$input") bytes, base64; base64 -d > file) ----"
            if [[ $(stat -c %s "$input") -le 65536 ]]; then base64 "$input"; else echo "(too large to print)"; fi
        done
    done
    echo "fuzz: findings in: ${failed[*]} (docs/fuzzing.md says how to reproduce and keep them)" >&2
    exit 1
fi
echo "fuzz: no findings in ${seconds}s per target"
