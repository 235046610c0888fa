#!/usr/bin/env bash
# The model-gap workflow's speed on the release build, paired: `fpc-sim gap` of this tree and
# of the reference commit (3b6fed0, the workflow before the residual's judgement, the sensor
# effects and the back-fitting) run in turn (ABAB…) on the same machine, on
#   - 10 s of closed-loop data at 10 kHz (45 strokes at 4 m/s, seed 52; cogging in the plant,
#     missing from the model),
#   - 36.6 s at 20 kHz (187 strokes, 732,184 rows, 137 MB of CSV; the same),
#   - each field log d01–d11 (tests/data/field-logs, gzipped as delivered, with its model),
# end to end (parsing, the analysis, the report and plots). Prints per log the best of N runs'
# wall time of each binary and their ratio (this tree over the reference) against the 0.40
# asked for, each binary's CPU time (user + sys, from its rusage, best of N) and their ratio,
# and what this tree named. Machines differ by more than the code does, hence the pairing. The
# CPU ratio says how much of a wall ratio is less work and how much more cores used. The ratios are
# figures, not checks (a shared machine's timing is noise): the script fails only if a run
# fails.
#
# The reference is built once from `git archive 3b6fed0` under
# ${CARGO_TARGET_DIR:-target}/gap-reference (a few minutes; kept for later runs) with the
# toolchain this tree pins. Each binary reads the log with its own commit's reference model
# (the same machine; the newer one has keys the older one rejects); the field logs' models
# load in both.
#
#   scripts/bench-gap.sh                  build both, then measure
#   FPC_SIM=path FPC_SIM_REF=path FPC_BENCH_RUNS=N FPC_BENCH_LOGS='10k d08' scripts/bench-gap.sh
#   FPC_SIM_REF=none ...                  this tree's figures alone (no reference built)
set -euo pipefail
cd "$(dirname "$0")/.."
export CARGO_BUILD_JOBS=${CARGO_BUILD_JOBS:-1}
ref_commit=3b6fed0
target=$(realpath -m "${CARGO_TARGET_DIR:-target}")
sim=${FPC_SIM:-}
if [[ -z $sim ]]; then
    cargo build --release -q -p hal-sim
    sim=$target/release/fpc-sim
fi
ref=${FPC_SIM_REF:-}
refroot=$target/gap-reference
if [[ $ref == none ]]; then
    echo "bench-gap: FPC_SIM_REF=none: this tree's figures alone, no ratio"
elif [[ -z $ref ]]; then
    ref=$refroot/target-$ref_commit/release/fpc-sim
    if [[ ! -x $ref ]]; then
        echo "bench-gap: building the reference fpc-sim at $ref_commit (once, a few minutes)"
        rm -rf "$refroot/$ref_commit"
        mkdir -p "$refroot/$ref_commit"
        git archive "$ref_commit" | tar -x -C "$refroot/$ref_commit"
        (cd "$refroot/$ref_commit" &&
            cargo build --release -q -p hal-sim --target-dir "$refroot/target-$ref_commit")
    fi
fi
runs=${FPC_BENCH_RUNS:-3}
logs=${FPC_BENCH_LOGS:-10k 732k d01 d02 d03 d04 d05 d06 d07 d08 d09 d10 d11}
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
# The model of each commit: its reference machine without the cogging section.
model_of() {
    awk '/^\[/ { skip = ($0 ~ /^\[effects\.cogging\]/) } !skip' "$1" > "$2"
    grep -q '^\[effects\.cogging\]' "$1" \
        || { echo "bench-gap: $1 has no [effects.cogging] to leave out"; exit 1; }
}
model_of hal-sim/src/plant/model/reference.toml "$work/model.toml"
git show "$ref_commit:hal-sim/src/plant/model/reference.toml" > "$work/reference-ref.toml"
model_of "$work/reference-ref.toml" "$work/model-ref.toml"
make_log() { # name cycles rate
    if ! "$sim" run --speed 4.0 --cycles "$2" --seed 52 --log-rate "$3" --out "$work/$1" \
            >"$work/$1.out" 2>&1; then
        echo "bench-gap: fpc-sim run could not make the $1 log; it printed:"
        tail -20 "$work/$1.out"
        df -h "$work" | sed 's/^/bench-gap: /'
        exit 1
    fi
}
for log in $logs; do
    case $log in
        10k) make_log 10k 45 10000 ;;
        732k) make_log 732k 187 20000 ;;
    esac
done
python3 - "$sim" "$ref" "$runs" "$work" "$logs" <<'PY'
import gzip, json, os, shutil, subprocess, sys, time

sim, ref, runs, work, logs = sys.argv[1], sys.argv[2], int(sys.argv[3]), sys.argv[4], sys.argv[5]
field = "tests/data/field-logs"
TARGET = 0.40


def inputs(log):
    """The measured log, this tree's model and the reference's."""
    if log in ("10k", "732k"):
        measured = os.path.join(work, log, "run.csv")
        return measured, os.path.join(work, "model.toml"), os.path.join(work, "model-ref.toml")
    model = os.path.join(field, f"{log}.toml")
    return os.path.join(field, f"{log}.csv.gz"), model, model


def rows(path):
    opener = gzip.open if path.endswith(".gz") else open
    with opener(path, "rt") as f:
        return sum(1 for line in f if not line.startswith("#")) - 1


def gap(binary, measured, model, out):
    """Wall time, CPU time (user + sys, from the rusage) and the effects named."""
    shutil.rmtree(out, ignore_errors=True)
    args = [binary, "gap", "--model", model, "--measured", measured, "--out", out, "--json"]
    with open(os.path.join(work, "gap.err"), "w+") as err:
        start = time.perf_counter()
        child = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=err, text=True)
        text = child.stdout.read()
        _, status, usage = os.wait4(child.pid, 0)
        wall = time.perf_counter() - start
        if os.waitstatus_to_exitcode(status) != 0:
            err.seek(0)
            sys.exit(f"bench-gap: {binary} gap on {measured} failed:\n{err.read()[-2000:]}")
    return wall, usage.ru_utime + usage.ru_stime, [e["name"] for e in json.loads(text)["effects"]]


print(f"bench-gap: fpc-sim gap, this tree ({sim}) against the reference ({ref}), run in "
      f"turn, best of {runs} each, on {os.cpu_count()} cores")
print(f"{'log':>5} {'rows':>8} {'ours s':>8} {'ref s':>8} {'ratio':>6} {'target':>6} "
      f"{'ours CPU s':>10} {'ref CPU s':>9} {'CPU ratio':>9}  named (ours)")
ratios = []
for log in logs.split():
    measured, model, model_ref = inputs(log)
    best, best_ref, cpu, cpu_ref, named = (float("inf"),) * 4 + (None,)
    for _ in range(runs):
        w, c, named = gap(sim, measured, model, os.path.join(work, "out"))
        best, cpu = min(best, w), min(cpu, c)
        if ref != "none":
            w, c, _ = gap(ref, measured, model_ref, os.path.join(work, "out-ref"))
            best_ref, cpu_ref = min(best_ref, w), min(cpu_ref, c)
    if ref == "none":
        print(f"{log:>5} {rows(measured):>8} {best:>8.2f} {'-':>8} {'-':>6} {'-':>6} "
              f"{cpu:>10.2f} {'-':>9} {'-':>9}  {named}", flush=True)
        continue
    ratio = best / best_ref
    ratios.append(ratio)
    print(f"{log:>5} {rows(measured):>8} {best:>8.2f} {best_ref:>8.2f} {ratio:>6.2f} "
          f"{'≤' + format(TARGET, '.2f'):>6} {cpu:>10.2f} {cpu_ref:>9.2f} {cpu / cpu_ref:>9.2f}  "
          f"{named}", flush=True)
if not ratios:
    sys.exit(0)
worst = max(ratios)
print(f"bench-gap: the largest ratio {worst:.2f} "
      f"({'within' if worst <= TARGET else 'above'} the {TARGET:.2f} asked for)")
PY
