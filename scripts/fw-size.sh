#!/usr/bin/env bash
# Firmware size budget: prints text/data/bss and flash/RAM use of the release ELF and fails
# if either exceeds its budget.
#
#   scripts/fw-size.sh            build with `cargo fw`, then measure
#   scripts/fw-size.sh ELF        measure an already built ELF
#
# Flash = text (vectors, code, read-only data) + data (its initial values);
# static RAM = data + bss (bss includes the .uninit RTT buffer). The stack is not static:
# it takes the rest of SRAM1 + SRAM2 (96 KiB). CCM SRAM (32 KiB) holds code, the 20 kHz
# interrupt path's (.ccmram, memory.x): printed on its own line, counted in flash (its image
# is stored there and copied at reset), not in the RAM budget, which is for data.
# Size tool: $SIZE if set, else the first of llvm-size, arm-none-eabi-size, size found
# (Berkeley output format, which all of them share).
set -euo pipefail

FLASH_BUDGET=$((128 * 1024))
RAM_BUDGET=$((32 * 1024))

cd "$(dirname "$0")/.."
elf=${1:-}
if [[ -z $elf ]]; then
    cargo fw
    elf=target/thumbv7em-none-eabihf/release/fpc
fi

tool=${SIZE:-}
if [[ -z $tool ]]; then
    for candidate in llvm-size arm-none-eabi-size size; do
        if command -v "$candidate" >/dev/null; then
            tool=$candidate
            break
        fi
    done
fi
if [[ -z $tool ]]; then
    echo "fw-size: no size tool (apt-get install llvm or binutils-arm-none-eabi)" >&2
    exit 2
fi

read -r text data bss < <("$tool" "$elf" | awk 'NR == 2 { print $1, $2, $3 }')
ccm=$("$tool" -A "$elf" | awk '$1 == ".ccmram" { print $2 }')
ccm=${ccm:-0}
CCM_BYTES=$((32 * 1024))
flash=$((text + data))
ram=$((data + bss))

pct() { echo "$(($1 * 1000 / $2))" | sed -E 's/(.)$/.\1/; s/^\./0./'; }
printf 'fw-size: %s (%s)\n' "$elf" "$tool"
printf '  text %8d  data %6d  bss %6d\n' "$text" "$data" "$bss"
printf '  flash %7d / %d bytes (%s %%)\n' "$flash" "$FLASH_BUDGET" "$(pct "$flash" "$FLASH_BUDGET")"
printf '  RAM   %7d / %d bytes (%s %%)\n' "$ram" "$RAM_BUDGET" "$(pct "$ram" "$RAM_BUDGET")"
printf '  CCM code %4d / %d bytes (%s %%): the 20 kHz path, run from CCM SRAM; code, in flash above, not RAM\n' \
    "$ccm" "$CCM_BYTES" "$(pct "$ccm" "$CCM_BYTES")"

status=0
if ((flash > FLASH_BUDGET)); then
    echo "fw-size: FAIL: flash over budget by $((flash - FLASH_BUDGET)) bytes" >&2
    status=1
fi
if ((ram > RAM_BUDGET)); then
    echo "fw-size: FAIL: static RAM over budget by $((ram - RAM_BUDGET)) bytes" >&2
    status=1
fi
exit $status
