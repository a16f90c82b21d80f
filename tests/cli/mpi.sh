#!/usr/bin/env bash
# freeform_mpi, as a user runs it (freeform/mpi/replica_exchange.hpp):
#   mpi.sh FREEFORM FREEFORM_MPI MPIEXEC SCENE WORK
# 1. `mpirun -np 1 freeform_mpi design` == `freeform design`, bit for bit (surface files)
# 2. tempering: two `mpirun -np 2` runs with the same seed write identical surface files
# 3. tempering: metrics.json has the replica fields (ranks, exchanges per pair, winner)
# 4. ranks x threads: 2 ranks x 2 threads write what 2 ranks x 1 thread write, and
#    metrics.json records each rank's threads and cores; rank 0 warns exactly when a
#    rank has more threads than the cores mpirun bound it to
# 5. a rank that dies ends the run non-zero, with no metrics.json or surface files
# 6. domains (the default mode): -np 1 == freeform design bit for bit; -np 2 twice
#    gives identical files, and 2 ranks x 2 threads the same as 2 x 1; metrics.json
#    records the mode, the merges and the moves of both ranks; a bad mode or a NaN coverage exits 2
set -uo pipefail
freeform=$1 freeform_mpi=$2 mpiexec=$3 scene=$4 work=$5
# Root in CI containers, and more ranks than cores on small machines.
mpirun=("$mpiexec" --allow-run-as-root --oversubscribe)
export OMPI_MCA_rmaps_base_oversubscribe=1
# Containers often forbid the cross-memory attach Open MPI's shared-memory transport uses
# for large messages (the winner's result); copy through shared memory instead.
export OMPI_MCA_btl_vader_single_copy_mechanism=none
rm -rf "$work" && mkdir -p "$work" && cd "$work" || exit 1
failures=0
fail() { echo "FAILED: $*"; failures=$((failures + 1)); }
files=(heightmap.pfm irradiance.pfm surface.obj surface.stl)

"$freeform" design "$scene" --out plain --threads 1 --quiet >plain.log 2>&1 || fail "freeform design: $(cat plain.log)"
"${mpirun[@]}" -np 1 "$freeform_mpi" design "$scene" --out np1 --threads 1 --quiet >np1.log 2>&1 ||
    fail "mpirun -np 1: $(cat np1.log)"
for f in "${files[@]}"; do
    cmp -s "plain/$f" "np1/$f" || fail "np 1: $f differs from the non-MPI design"
done
[ $failures -eq 0 ] && echo "ok   np 1 == freeform design, bit for bit (${files[*]})"

for run in a b; do
    "${mpirun[@]}" -np 2 "$freeform_mpi" design "$scene" --out "np2$run" --threads 1 --quiet --exchange-every 100 \
        --replica-mode tempering \
        >"np2$run.log" 2>&1 || fail "mpirun -np 2 (run $run): $(cat "np2$run.log")"
done
before=$failures
for f in "${files[@]}"; do
    cmp -s "np2a/$f" "np2b/$f" || fail "np 2: $f differs between two runs with the same seed"
done
[ $failures -eq $before ] && echo "ok   np 2 twice, same seed: identical surface files"

python3 - np2a/metrics.json <<'PY' || fail "np 2: metrics.json replica fields"
import json, sys
m = json.load(open(sys.argv[1]))
r = m["replicas"]
assert r["ranks"] == 2, r
assert r["exchange_points"] >= 5, r  # design-tiny: 2000 iterations, every 100
assert len(r["pairs"]) == 1 and r["pairs"][0]["rungs"] == [0, 1], r
p = r["pairs"][0]
assert p["proposed"] == r["exchange_points"] and 0 <= p["accepted"] <= p["proposed"], p
assert r["winner_rank"] in (0, 1) and len(r["objectives"]) == 2, r
assert r["objectives"][r["winner_rank"]] == min(r["objectives"]), r
# The winner is picked on the held-out rays (held-out checks are on by default).
assert r["objectives_judged_on"] == "held-out rays", r
assert abs(m["objective_held_out"] - r["objectives"][r["winner_rank"]]) < 1e-12, (m["objective_held_out"], r)
assert r["iterations_all_ranks"] == 4000, r
print("ok   metrics.json: ranks 2, %d exchanges proposed, %d accepted, winner rank %d"
      % (p["proposed"], p["accepted"], r["winner_rank"]))
PY

# Hybrid: unbound (--bind-to none: each rank may use every core), then mpirun's default
# binding (one core per rank for 2 ranks on a machine with 2 or more cores).
before=$failures
"${mpirun[@]}" --bind-to none -np 2 "$freeform_mpi" design "$scene" --out np2t2 --threads 2 --quiet \
    --exchange-every 100 --replica-mode tempering >np2t2.log 2>&1 || fail "mpirun -np 2 --threads 2 (unbound): $(cat np2t2.log)"
"${mpirun[@]}" -np 2 "$freeform_mpi" design "$scene" --out np2t2bound --threads 2 --quiet \
    --exchange-every 100 --replica-mode tempering >np2t2bound.log 2>&1 || fail "mpirun -np 2 --threads 2 (bound): $(cat np2t2bound.log)"
for d in np2t2 np2t2bound; do
    for f in "${files[@]}"; do
        cmp -s "np2a/$f" "$d/$f" || fail "$d: $f differs from 2 ranks x 1 thread"
    done
done
python3 - np2t2 np2t2bound np2a <<'PY' || fail "ranks x threads: metrics.json or the warning"
import json, os, sys
cores_here = len(os.sched_getaffinity(0))
for d in sys.argv[1:]:
    r = json.load(open(d + "/metrics.json"))["replicas"]
    threads = 1 if d == "np2a" else 2
    assert r["threads_per_rank"] == [threads, threads], (d, r["threads_per_rank"])
    cores = r["cores_per_rank"]
    assert len(cores) == 2 and all(1 <= c <= cores_here for c in cores), (d, cores)
    if d == "np2t2":
        assert cores == [cores_here, cores_here], (d, cores, cores_here)
    over = any(t > c for t, c in zip(r["threads_per_rank"], cores))
    warned = "warning: rank" in open(d + ".log").read()
    assert over == warned, (d, "threads over cores" if over else "threads within cores",
                            "warned" if warned else "no warning")
    print("ok   %s: %d ranks x %s threads on %s cores%s" % (d, len(cores), r["threads_per_rank"], cores,
                                                        ", warned" if warned else ""))
PY
[ $failures -eq $before ] && echo "ok   2 ranks x 2 threads (bound and unbound) == 2 ranks x 1 thread, bit for bit"

# Domains: the ranks share one design, each moving a strip of the mesh.
before=$failures
"${mpirun[@]}" -np 1 "$freeform_mpi" design "$scene" --out dom1 --threads 1 --quiet --replica-mode domains \
    >dom1.log 2>&1 || fail "domains -np 1: $(cat dom1.log)"
for f in "${files[@]}"; do
    cmp -s "plain/$f" "dom1/$f" || fail "domains np 1: $f differs from the non-MPI design"
done
for run in a b; do
    "${mpirun[@]}" -np 2 "$freeform_mpi" design "$scene" --out "dom2$run" --threads 1 --quiet \
        --exchange-every 150 >"dom2$run.log" 2>&1 || fail "domains -np 2: $(cat "dom2$run.log")"
done
"${mpirun[@]}" --bind-to none -np 2 "$freeform_mpi" design "$scene" --out dom2t2 --threads 2 --quiet \
    --replica-mode domains --exchange-every 150 >dom2t2.log 2>&1 || fail "domains -np 2 --threads 2: $(cat dom2t2.log)"
for d in dom2b dom2t2; do
    for f in "${files[@]}"; do
        cmp -s "dom2a/$f" "$d/$f" || fail "domains: $d/$f differs from the first 2-rank run"
    done
done
python3 - dom2a/metrics.json plain/metrics.json <<'PY' || fail "domains: metrics.json"
import json, sys
m = json.load(open(sys.argv[1]))
plain = json.load(open(sys.argv[2]))
r = m["replicas"]
assert r["ranks"] == 2 and r["mode"] == "domains", r
assert r["rows_per_rank"] == [[0, 0.5], [0.5, 1]], r
assert r["merges"] >= 5 and "pairs" not in r, r  # design-tiny: 2000 iterations a rank in 3 stages, merges every 150
assert r["iterations_all_ranks"] == 4000 and m["iterations"] == 4000, (r, m["iterations"])
assert all(l.get("merges", 0) >= 1 for l in m["levels"]), m["levels"]
assert r["winner_rank"] == 0, r  # every rank ends on the same surface
# Twice the moves of the plain design (the same iterations a rank) and a sane result.
assert 0 < m["error"] < m["start"]["error"] or m["error"] < 2 * plain["error"], (m["error"], plain["error"])
print("ok   domains metrics.json: %d merges, %d moves in all, error %.4f (plain design %.4f)"
      % (r["merges"], m["iterations"], m["error"], plain["error"]))
PY
"${mpirun[@]}" -np 2 "$freeform_mpi" design "$scene" --out dombad --threads 1 --quiet --replica-mode tiles \
    >dombad.log 2>&1
rc=$?
[ $rc -eq 2 ] || fail "--replica-mode tiles: exit code $rc, not 2"
grep -q -- "--replica-mode" dombad.log || fail "--replica-mode tiles: the message does not name the option: $(cat dombad.log)"
[ ! -e dombad/metrics.json ] || fail "--replica-mode tiles: metrics.json written"
"${mpirun[@]}" -np 1 "$freeform_mpi" design "$scene" --out dombad2 --threads 1 --quiet --merge-coverage nan \
    >dombad2.log 2>&1
rc=$?
[ $rc -eq 2 ] || fail "--merge-coverage nan: exit code $rc, not 2"
grep -q -- "--merge-coverage: must be a finite number" dombad2.log ||
    fail "--merge-coverage nan: the message does not name the option: $(cat dombad2.log)"
[ ! -e dombad2/metrics.json ] || fail "--merge-coverage nan: metrics.json written"
[ $failures -eq $before ] && echo "ok   domains: np 1 == freeform design; np 2 reproducible, threads change nothing; bad mode or coverage exits 2"

FREEFORM_TEST_ABORT_RANK=1 "${mpirun[@]}" -x FREEFORM_TEST_ABORT_RANK -np 2 "$freeform_mpi" design "$scene" \
    --out dead --threads 1 --quiet >dead.log 2>&1
rc=$?
before=$failures
[ $rc -ne 0 ] || fail "a dead rank: exit code 0"
for f in metrics.json "${files[@]}" convergence.csv; do
    [ ! -e "dead/$f" ] || fail "a dead rank: dead/$f was written"
done
grep -q "rank 1" dead.log || fail "a dead rank: the message does not name rank 1: $(cat dead.log)"
[ $failures -eq $before ] && echo "ok   a dead rank: exit code $rc, no output files; mpirun said:"
sed 's/^/       /' dead.log | head -20

[ $failures -eq 0 ] || { echo "$failures check(s) failed"; exit 1; }
