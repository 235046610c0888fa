#!/usr/bin/env bash
# Builds a bring-up test firmware (a feature of Cargo.toml's [features], e.g.
# test-panic-on-stop) with the release profile and copies its ELF to target/fpc-FEATURE, for
# the PIL's tests (pil/tests). The release ELF (target/thumbv7em-none-eabihf/release/fpc) is
# rebuilt afterwards: the feature build writes the same path, and cargo keeps both artifacts,
# so switching back only re-links. For the bench, `cargo fw-test FEATURE` builds the same code
# with debug info (target/thumbv7em-none-eabihf/bringup/fpc).
#
#   scripts/fw-test-elf.sh FEATURE
set -euo pipefail
cd "$(dirname "$0")/.."
feature=${1:?usage: scripts/fw-test-elf.sh FEATURE}
if ! grep -q "^${feature} = \[\]" Cargo.toml; then
    echo "fw-test-elf: no feature ${feature} in Cargo.toml" >&2
    exit 2
fi
cargo build --release --target thumbv7em-none-eabihf --bin fpc --features "$feature"
cp target/thumbv7em-none-eabihf/release/fpc "target/fpc-${feature}"
cargo fw
echo "fw-test-elf: target/fpc-${feature}"
