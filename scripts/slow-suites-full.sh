#!/usr/bin/env bash
# The full run: every slow suite (#[ignore]) at its full size, on the optimised slow-tests
# profile — what CI runs as slices (docs/testing.md, "Slow suites") — with the timings the
# benchmarks assert only in an optimised build. Run it before a release, or when a suite's
# code changes, and write its figures and the date into docs/testing.md ("The full run").
#
#   bash scripts/slow-suites-full.sh [TESTNAME-FILTER…]   # ≈ 2 h on two cores
#
# The size variables CI sets are cleared here, so every suite takes its full default.
set -euo pipefail
cd "$(dirname "$0")/.."
unset FPC_HOSTILE_CASES FPC_FAULT_RUNS FPC_FUZZ_INPUTS FPC_NULL_STRIDE FPC_MEMORY_CYCLES \
    FPC_FORM_CASES FPC_FIELD_FORM_CASES FPC_GAP_BENCH_STRIDE FPC_LINK_SPEEDS FPC_BENCH_RUNS FPC_FAULT_ROTATION
started=$SECONDS
date -u '+full run started %Y-%m-%d %H:%M UTC'
git log -1 --format='at commit %h (%s)'
cargo test --workspace --profile slow-tests --no-run
# The benchmarks alone first (their timings are CPU seconds of an otherwise idle process),
# then everything else; then the scenarios as an expander (docs/faults.md #25).
cargo test --workspace --profile slow-tests -- --ignored --nocapture --test-threads 1 \
    gap_analyses_10_s_at_10_khz_within_3_s closed_loop_realtime_factor where_the_cycle_time_goes
cargo test --workspace --profile slow-tests -- --ignored --nocapture \
    --skip gap_analyses_10_s_at_10_khz_within_3_s --skip closed_loop_realtime_factor \
    --skip where_the_cycle_time_goes "$@"
FPC_FAULT_ROTATION=expander cargo test --workspace --profile slow-tests \
    --test faults_are_caught_and_the_machine_stays_safe
printf 'full run: %d min %d s\n' $((( SECONDS - started) / 60)) $((( SECONDS - started) % 60))
