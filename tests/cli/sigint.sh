#!/usr/bin/env bash
# Ctrl-C during `freeform design`: the run stops at the next progress point, writes the
# best result so far (metrics.json with "interrupted": true, heightmap.pfm, ...) and
# exits with 130.
#
#   sigint.sh <freeform executable> <scene.json> <work directory>
set -u
freeform=$1
scene=$2
work=$3

rm -rf "$work"
mkdir -p "$work"
cd "$work" || exit 1

"$freeform" design "$scene" --out out --quiet >stdout.txt 2>stderr.txt &
pid=$!

# Wait until the program has installed its SIGINT handler (before that, a background
# job of a non-interactive shell ignores SIGINT): bit 2 of SigCgt in /proc. Without
# /proc, give it a generous head start.
caught=0
for _ in $(seq 1 600); do
    if ! kill -0 "$pid" 2>/dev/null; then break; fi
    if [ -r "/proc/$pid/status" ]; then
        mask=$(awk '/^SigCgt:/ {print $2}' "/proc/$pid/status")
        if [ -n "$mask" ] && (( (16#$mask >> 1) & 1 )); then caught=1; break; fi
    else
        sleep 5
        caught=1
        break
    fi
    sleep 0.1
done
if [ "$caught" != 1 ]; then
    echo "FAILED: freeform never installed a SIGINT handler (or exited early)"
    cat stdout.txt stderr.txt
    kill -9 "$pid" 2>/dev/null
    exit 1
fi

# Let the design run a while, then interrupt it.
sleep 2
if ! kill -0 "$pid" 2>/dev/null; then
    echo "FAILED: the design ended before it was interrupted (make the scene's budget longer)"
    cat stdout.txt stderr.txt
    exit 1
fi
kill -INT "$pid"
start=$SECONDS

# It must stop promptly; kill it if it does not.
while kill -0 "$pid" 2>/dev/null; do
    if (( SECONDS - start > 120 )); then
        echo "FAILED: still running 120 s after SIGINT"
        kill -9 "$pid"
        exit 1
    fi
    sleep 0.1
done
wait "$pid"
rc=$?

failed=0
check() {
    if ! eval "$1"; then
        echo "FAILED: $2"
        failed=1
    fi
}
check '[ "$rc" = 130 ]' "exit code $rc, expected 130"
check '[ ! -s stderr.txt ]' "stderr is not empty: $(cat stderr.txt)"
check 'grep -q "^interrupted" stdout.txt' "stdout does not say it was interrupted: $(cat stdout.txt)"
for f in metrics.json heightmap.pfm convergence.csv surface.obj surface.stl irradiance.png target.png comparison.png; do
    check "[ -s out/$f ]" "out/$f was not written"
done
check 'grep -Eq "\"interrupted\": *true" out/metrics.json' "metrics.json does not hold \"interrupted\": true"
check 'head -c 3 out/heightmap.pfm | grep -q "^Pf"' "heightmap.pfm is not a grey PFM"
if [ "$failed" = 0 ]; then
    echo "ok: interrupted after $((SECONDS - start)) s, exit code 130, results written"
fi
exit "$failed"
