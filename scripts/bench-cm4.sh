#!/usr/bin/env bash
# Cortex-M4 instruction counts of the control logic (bench/cm4), run in QEMU's mps2-an386.
#
# Prints one line per function (`bench NAME: N instructions/call`) and exits non-zero if the
# build or QEMU fails, QEMU hangs (timeout), the calibration is off or a budget is exceeded.
# Counts are exact and identical run after run (-icount: virtual time counts instructions).
#
# Needs: qemu-system-arm (apt-get install -y qemu-system-arm) and
#        rustup target add thumbv7em-none-eabihf.
set -euo pipefail

command -v qemu-system-arm >/dev/null ||
    { echo "bench-cm4: qemu-system-arm not found (apt-get install -y qemu-system-arm)" >&2; exit 1; }

root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bench="$root/bench/cm4"
elf="$bench/target/thumbv7em-none-eabihf/release/fpc-bench-cm4"

# The link script comes from the bench's build.rs. An empty RUSTFLAGS overrides every config
# file's rustflags, so firmware link flags in a root .cargo/config.toml (-Tlink.x -Tdefmt.x)
# cannot add a second -Tlink.x to this link.
cd "$bench"
# --target-dir: the ELF read below is the one just built, whatever CARGO_TARGET_DIR says.
RUSTFLAGS="" cargo build --release --target thumbv7em-none-eabihf \
    --manifest-path "$bench/Cargo.toml" --target-dir "$bench/target"

# -icount shift=10: each instruction is 1024 ns of virtual time, which the bench's timer
# arithmetic assumes (its calibration fails otherwise). 120 s is ~50x the normal run time.
status=0
timeout 120 qemu-system-arm -machine mps2-an386 -cpu cortex-m4 -nographic \
    -semihosting-config enable=on,target=native -icount shift=10 -kernel "$elf" || status=$?

case $status in
    0) ;;
    124) echo "bench-cm4: QEMU timed out (hang or HardFault loop)" >&2; exit 1 ;;
    *) echo "bench-cm4: FAILED (exit $status: budget exceeded, calibration off or panic)" >&2
       exit "$status" ;;
esac
