#!/usr/bin/env bash
# Builds the mutation tests' firmware: the release build with one deliberate mistake each
# (src/board/mutation.rs, FPC_MUTATION=<name>), copied to target/mutants/fpc-<name>; then the
# release ELF again. Only the firmware binary crate reads FPC_MUTATION, so each mutant
# recompiles and relinks that crate alone (the library and the dependencies are reused).
# `fpc-pil mutants --elf target/thumbv7em-none-eabihf/release/fpc --dir target/mutants` then
# checks that each is caught.
#
#   scripts/fw-mutants.sh
set -euo pipefail
cd "$(dirname "$0")/.."
out=target/mutants
mkdir -p "$out"
# The names, from the one list in the firmware.
names=$(sed -n '/^pub const ALL/,/^\];/p' src/board/mutation.rs | grep -o '"[a-z0-9-]*"' | tr -d '"')
count=0
for name in $names; do
    FPC_MUTATION="$name" cargo build --quiet --release --target thumbv7em-none-eabihf --bin fpc
    cp target/thumbv7em-none-eabihf/release/fpc "$out/fpc-$name"
    count=$((count + 1))
done
cargo fw --quiet
echo "fw-mutants: $count mutants in $out"
