#!/usr/bin/env bash
# The model-gap workflow's speed against a reference commit's binary, on the same machine:
# machines (and a shared machine's moments) differ by more than the code does, so speed is
# judged paired. `fpc-sim gap` of this tree and of the reference (3b6fed0, the commit before
# issue #45) run in turn — A B A B … — on the 732k-row log (36.6 s at 20 kHz: 187 strokes at
# 4 m/s, seed 52, made by `fpc-sim run`; cogging in the plant, missing from the model) and on
# each field log of tests/data/field-logs, end to end (reading, analysis, report). Prints per
# log the median of the pairs' wall-time ratios (this tree / reference; issue #45 asks for
# ≤ 0.40) with both binaries' median wall and CPU times. Figures, not checks.
#
# The reference is built once from the commit's files (git archive, so no worktree is
# registered in the repository) in a temporary directory with a target directory of its
# own, then only its binary is kept (target/bench-ref/fpc-sim-<commit>; the build, several
# minutes on two cores, is skipped while that file exists) and the sources and their target
# directory are removed.
#
#   scripts/bench-gap.sh                        build both, then measure (3 pairs per log)
#   FPC_SIM=path FPC_GAP_REF_SIM=path FPC_BENCH_PAIRS=N FPC_GAP_LOGS="d01 d09" scripts/bench-gap.sh
#   FPC_GAP_REF=<commit>                        another reference commit
#   FPC_GAP_LONG=0                              the field logs only
set -euo pipefail
cd "$(dirname "$0")/.."
sim=${FPC_SIM:-}
if [[ -z $sim ]]; then
    cargo build --release -q -p hal-sim
    sim=${CARGO_TARGET_DIR:-target}/release/fpc-sim
fi
ref=${FPC_GAP_REF:-3b6fed0}
ref_sim=${FPC_GAP_REF_SIM:-target/bench-ref/fpc-sim-$ref}
if [[ ! -x $ref_sim ]]; then
    started=$SECONDS
    mkdir -p target/bench-ref
    tree=$(mktemp -d)
    mkdir "$tree/src"
    git archive "$ref" | tar -x -C "$tree/src"
    (cd "$tree/src" && CARGO_TARGET_DIR="$tree/target" cargo build --release -q -p hal-sim)
    cp "$tree/target/release/fpc-sim" "$ref_sim"
    rm -rf "$tree"
    echo "bench-gap: built the reference $ref in $((SECONDS - started)) s (kept as $ref_sim)"
fi
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
logs=()
if [[ ${FPC_GAP_LONG:-1} != 0 ]]; then
    if ! "$sim" run --speed 4.0 --cycles 187 --seed 52 --log-rate 20000 --out "$work/long" \
            >"$work/run.out" 2>&1; then
        echo "bench-gap: fpc-sim run could not make the 137 MB log; it printed:"
        tail -20 "$work/run.out"
        df -h "$work" | sed 's/^/bench-gap: /'
        exit 1
    fi
    # The model both binaries read: the reference commit's reference machine (keys added
    # since are refused by the older binary, and their defaults change nothing).
    git show "$ref:hal-sim/src/plant/model/reference.toml" > "$work/ref-reference.toml"
    awk '/^\[/ { skip = ($0 ~ /^\[effects\.cogging\]/) } !skip' \
        "$work/ref-reference.toml" > "$work/long-model.toml"
    grep -q '^\[effects\.cogging\]' "$work/ref-reference.toml" \
        || { echo "bench-gap: the reference model has no [effects.cogging] to leave out"; exit 1; }
    logs+=("long:$work/long-model.toml:$work/long/run.csv")
fi
for d in ${FPC_GAP_LOGS:-$(cd tests/data/field-logs && ls d*.csv.gz | sed 's/.csv.gz//')}; do
    logs+=("$d:tests/data/field-logs/$d.toml:tests/data/field-logs/$d.csv.gz")
done
python3 - "$sim" "$ref_sim" "${FPC_BENCH_PAIRS:-3}" "$work" "$ref" "${logs[@]}" <<'PY'
import os, shutil, statistics, subprocess, sys, time

sim, ref_sim, pairs, work, ref = sys.argv[1], sys.argv[2], int(sys.argv[3]), sys.argv[4], sys.argv[5]


def run(binary, model, log, out):
    shutil.rmtree(out, ignore_errors=True)
    args = [binary, "gap", "--model", model, "--measured", log, "--out", out, "--json"]
    start = time.perf_counter()
    child = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    _, status, usage = os.wait4(child.pid, 0)
    wall = time.perf_counter() - start
    if os.waitstatus_to_exitcode(status) != 0:
        sys.exit(f"bench-gap: {binary} gap on {log} failed")
    return wall, usage.ru_utime + usage.ru_stime


print(f"gap, this tree against {ref}, {pairs} pairs per log run in turn (wall ratio: median "
      f"of the pairs; issue #45 asks for <= 0.40), on {os.cpu_count()} cores")
print(f"{'log':<6} {'ratio':>6} {'this wall':>10} {'ref wall':>9} {'this CPU':>9} {'ref CPU':>8}")
worst = 0.0
for spec in sys.argv[6:]:
    name, model, log = spec.split(":", 2)
    this, base = [], []
    for _ in range(pairs):
        base.append(run(ref_sim, model, log, os.path.join(work, "ref")))
        this.append(run(sim, model, log, os.path.join(work, "this")))
    ratio = statistics.median(t[0] / b[0] for t, b in zip(this, base))
    worst = max(worst, ratio)
    med = lambda v, i: statistics.median(x[i] for x in v)
    print(f"{name:<6} {ratio:>6.2f} {med(this, 0):>9.2f}s {med(base, 0):>8.2f}s "
          f"{med(this, 1):>8.2f}s {med(base, 1):>7.2f}s", flush=True)
print(f"worst ratio {worst:.2f}")
PY
