#!/usr/bin/env bash
# Mutation check: each line below breaks the code a test guards, in a way the test's earlier
# form let through (docs/testing.md, "Tests that can fail"), runs that test and expects it to
# FAIL; the file is restored after each. A mutation whose text is no longer found is an error
# (the table must follow the code), and so is a mutated test that passes.
#
#   bash scripts/mutations.sh [NAME…]     # every mutation, or those named; ≈ 3 min each
set -euo pipefail
cd "$(dirname "$0")/.."

# mutation NAME FILE FIND REPLACE TEST-ARGS…: FIND (literal, found exactly once) becomes REPLACE.
want=("$@")
failed=0
mutation() {
    local name=$1 file=$2 find=$3 replace=$4
    shift 4
    if ((${#want[@]})) && [[ ! " ${want[*]} " == *" $name "* ]]; then return; fi
    local count
    count=$(grep -cF -- "$find" "$file" || true)
    if [[ $count != 1 ]]; then
        echo "mutation $name: its text is found $count times in $file (the table must follow the code)"
        failed=1
        return
    fi
    cp "$file" "$file.orig"
    trap 'mv "$file.orig" "$file"' EXIT
    FIND=$find REPLACE=$replace perl -0pi -e 's/\Q$ENV{FIND}\E/$ENV{REPLACE}/' "$file"
    local log="target/mutation-$name.log" started=$SECONDS
    if cargo test "$@" -- --nocapture >"$log" 2>&1; then
        echo "mutation $name: NOT caught: cargo test $* passed ($((SECONDS - started)) s)"
        failed=1
    elif ! grep -q "^running [1-9]" "$log"; then
        echo "mutation $name: no test ran, or the build failed ($log)"
        failed=1
    else
        echo "mutation $name: caught by cargo test $* ($((SECONDS - started)) s)"
        grep -m1 -A1 "panicked at" "$log" | sed 's/^/    /' || true
    fi
    mv "$file.orig" "$file"
    trap - EXIT
}

mutation motor-and-gas-force-1.01 src/physics/balance.rs \
    'mass_kg * accel_mps2 - self.motor_n' \
    'mass_kg * accel_mps2 - T::of(0.01) * (self.motor_n + self.gas_n) - self.motor_n' \
    --test forces_and_gap_leave_the_same_force_unexplained both_recover
mutation leak-law-20pc src/physics/gas.rs \
    '/ (T::of(24.0)' '/ (T::of(20.0)' \
    --test chamber_physics leaks_down
mutation backward-difference-a-sample-later hal-sim/src/cli/filters.rs \
    'let raw = backward_difference(x, dt);' \
    'let mut raw = backward_difference(x, dt); raw.rotate_right(1);' \
    --test analysis_commands on_a_simulator_run
mutation log-ranges-dropped hal-sim/src/runlog.rs \
    'ranges = names.iter().map(|n| physical_range(n)).collect();' \
    'ranges = names.iter().map(|_| (f64::MIN, f64::MAX)).collect();' \
    --test parsers_survive_fuzzing parsers_refuse_fuzzed_input
mutation example-model-out-of-range docs/examples/model.toml \
    'mass_kg = 12.0 ' 'mass_kg = 1.0e4' \
    -p hal-sim --test model_values_are_refused_outside_their_range every_model
mutation encoder-error-limit-130 src/sensing/encoder.rs \
    'error_limit: 80,' 'error_limit: 130,' \
    --test encoder_signal_faults_are_caught a_burst_latches_at_its_second_or_third
mutation bad-input-exits-1 hal-sim/src/failure.rs \
    'code: 2,' 'code: 1,' \
    --test fpc_sim_survives_hostile_input every_subcommand_survives_hostile_input
exit $failed
