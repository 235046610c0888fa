#!/usr/bin/env python3
"""Where the control step's instructions go: an exact per-stage count from a QEMU trace.

Reads QEMU's `-d exec,nochain -singlestep` log of the bench-cm4 ELF (one line per executed
instruction) from a file or FIFO, cuts it into calls of `ControlStep::step` (entry at the
symbol, exit where the call returns to) and attributes every
instruction to the chain of functions inlined at its address (DWARF, `addr2line -i`).

The bench calls the step in a fixed order (bench/cm4/src/main.rs): settling into holding,
CALLS holding, 2 x CALLS to get a stroke going, 4 x CALLS running. The last 4 x CALLS calls are
the running regime, the CALLS before the 2 x CALLS the holding one.

Usage: profile-cm4.py ELF TRACE [--depth N] [--top N] [--lines N]
Prints, per regime, the mean instructions per step (the bench's figure less its call
overhead) and the inlined stages under the step, `depth` frames deep, most expensive first;
with --lines, also the N source lines (of the innermost function inlined at each address)
that execute the most instructions, running beside holding.
"""

import argparse
import collections
import re
import subprocess
import sys

CALLS = 1000
STEP = re.compile(r"ControlStep4step17h[0-9a-f]{16}E$")
TRACE_PC = re.compile(rb"\[[0-9a-f]+/([0-9a-f]+)/")


def step_symbol(elf):
    """The step's entry address."""
    out = subprocess.run(["nm", elf], capture_output=True, text=True, check=True).stdout
    for line in out.splitlines():
        parts = line.split()
        if len(parts) == 3 and STEP.search(parts[2]):
            return int(parts[0], 16) & ~1
    sys.exit("profile-cm4: no ControlStep::step symbol in the ELF")


def calls(trace, entry):
    """One Counter of program counters per call of the step, in order. A call ends where it
    returns to: four bytes after the `bl` that entered it (the instruction traced before the
    entry; Thumb-2 `bl` is 32 bits)."""
    out, cur, prev, ret = [], None, None, None
    with open(trace, "rb") as f:
        for line in f:
            m = TRACE_PC.search(line)
            if not m:
                continue
            pc = int(m.group(1), 16)
            if cur is None:
                if pc == entry and prev is not None:
                    cur, ret = collections.Counter({pc: 1}), prev + 4
            elif pc == ret:
                out.append(cur)
                cur = None
            else:
                cur[pc] += 1
            prev = pc
    return out


def inline_chains(elf, pcs):
    """For each address, its inlined functions, outermost first, as `function@file:line`."""
    out = subprocess.run(["addr2line", "-e", elf, "-f", "-i", "-C", "-a"]
                         + [hex(p) for p in pcs], capture_output=True, text=True,
                         check=True).stdout.splitlines()
    chains, pc, frames = {}, None, []
    for line in out + ["0x0"]:
        if line.startswith("0x"):
            if pc is not None:
                pairs = list(zip(frames[0::2], frames[1::2]))[::-1]
                chains[pc] = [
                    re.sub(r"::h[0-9a-f]{16}$", "", f).replace("fpc::", "").replace("control::step::", "")
                    + "@" + loc.split(" ")[0].split("/")[-1]
                    for f, loc in pairs
                ]
            pc, frames = int(line, 16), []
        else:
            frames.append(line)
    return chains


def report(name, selected, chains, depth, top):
    total = collections.Counter()
    for c in selected:
        total.update(c)
    n = len(selected)
    print(f"{name}: {sum(total.values()) / n:.1f} instructions per step over {n} steps")
    stages = collections.Counter()
    for pc, k in total.items():
        chain = chains.get(pc, ["?"])
        # The last frame's line is where the instruction is: keep it only for the innermost.
        key = " > ".join(f.split("@")[0] if i + 1 == len(chain[:depth]) else f
                         for i, f in enumerate(chain[:depth]))
        stages[key] += k
    for key, k in stages.most_common(top):
        print(f"  {k / n:7.1f}  {key}")


def report_lines(running, holding, chains, top):
    """The source lines executing the most instructions per step, running and holding."""
    per = {}
    for name, selected in (("running", running), ("holding", holding)):
        total = collections.Counter()
        for c in selected:
            total.update(c)
        lines = collections.Counter()
        for pc, k in total.items():
            line = chains.get(pc, ["?@?"])[-1].split("@")[-1]
            lines[line] += k / len(selected)
        per[name] = lines
    print(f"source lines, instructions per step (running, holding), top {top}:")
    for line, k in per["running"].most_common(top):
        print(f"  {k:7.1f} {per['holding'][line]:7.1f}  {line}")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("elf")
    ap.add_argument("trace")
    ap.add_argument("--depth", type=int, default=4)
    ap.add_argument("--top", type=int, default=25)
    ap.add_argument("--lines", type=int, default=0)
    a = ap.parse_args()
    entry = step_symbol(a.elf)
    every = calls(a.trace, entry)
    if len(every) < 7 * CALLS:
        sys.exit(f"profile-cm4: {len(every)} calls of the step traced, fewer than the bench's")
    running = every[-4 * CALLS:]
    holding = every[-7 * CALLS:-6 * CALLS]
    pcs = sorted(set().union(*running, *holding))
    chains = inline_chains(a.elf, pcs)
    report("control_step_holding", holding, chains, a.depth, a.top)
    report("control_step_running", running, chains, a.depth, a.top)
    if a.lines:
        report_lines(running, holding, chains, a.lines)


if __name__ == "__main__":
    main()
