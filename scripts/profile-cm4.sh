#!/usr/bin/env bash
# Where the 20 kHz control step's instructions go, by inlined stage, holding and running.
#
# Builds and runs the bench (scripts/bench-cm4.sh), then runs its ELF again in QEMU with one
# instruction per translation block and every executed block logged, and attributes each
# executed instruction of the step's calls to the functions inlined at its address
# (scripts/profile-cm4.py). Exact, like the bench: the figures are instruction counts.
# About 2 minutes. Extra arguments go to the Python part (--depth N, --top N, --lines N).
#
# Needs: what bench-cm4.sh needs, python3, binutils (nm, addr2line).
set -uo pipefail

root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
elf="$root/bench/cm4/target/thumbv7em-none-eabihf/release/fpc-bench-cm4"

# The bench must build and pass its budgets first; its figures are the reference.
bash "$root/scripts/bench-cm4.sh" | grep -E "control_step_(holding|running)" || exit 1

work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
mkfifo "$work/trace"
python3 "$root/scripts/profile-cm4.py" "$elf" "$work/trace" "$@" &
reader=$!
timeout 1200 qemu-system-arm -machine mps2-an386 -cpu cortex-m4 -nographic \
    -semihosting-config enable=on,target=native -icount shift=10 -singlestep \
    -d exec,nochain -D "$work/trace" -kernel "$elf" >/dev/null
qemu=$?
wait "$reader"
status=$?
[ "$qemu" -eq 0 ] || { echo "profile-cm4: QEMU failed (exit $qemu)" >&2; exit 1; }
exit "$status"
