#!/usr/bin/env python3
"""Runs the README's tour and checks that what it prints is what the tools print.

Every ```console block of README.md is a session: a line `$ CMD` is run, the lines after it
(up to the next `$` line or the block's end) are what it must print, in order; other lines
may come between them (cargo's progress, for instance). In an expected line `…` stands for
anything (wall-clock figures). `fpc-sim` commands run the release build
(`target/release/fpc-sim`) in a scratch directory that sees the repository's `tests/` and
`docs/`, so the tour writes nothing into the checkout; other commands (`cargo fw`, `bash
scripts/…`) run in the repository.

Usage: python3 scripts/check-readme.py [README]   (exit 1 naming every line that differs)
Needs the release build: cargo build --release -p hal-sim.
"""

import os
import re
import shlex
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def sessions(text):
    """Yield (line number, command, [expected lines]) for every `$` line in console blocks."""
    in_block = False
    current = None
    for number, line in enumerate(text.splitlines(), 1):
        if line.startswith("```"):
            if in_block and current:
                yield current
                current = None
            in_block = line.strip() == "```console" if not in_block else False
            continue
        if not in_block:
            continue
        if line.startswith("$ "):
            if current:
                yield current
            current = (number, line[2:].strip(), [])
        elif current:
            current[2].append(line)


def pattern(expected):
    parts = [re.escape(p) for p in expected.split("…")]
    return re.compile("^" + ".*?".join(parts) + "$")


def run(command, scratch):
    words = shlex.split(command)
    if words[0] == "fpc-sim":
        words[0] = os.path.join(ROOT, "target", "release", "fpc-sim")
        cwd = scratch
    else:
        cwd = ROOT
    done = subprocess.run(words, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                          text=True, timeout=900)
    return done.returncode, done.stdout.splitlines()


def main():
    readme = sys.argv[1] if len(sys.argv) > 1 else os.path.join(ROOT, "README.md")
    with open(readme, encoding="utf-8") as f:
        text = f.read()
    binary = os.path.join(ROOT, "target", "release", "fpc-sim")
    if not os.path.exists(binary):
        sys.exit(f"check-readme: {binary} is missing (cargo build --release -p hal-sim)")
    failures = []
    count = 0
    with tempfile.TemporaryDirectory(prefix="fpc-readme-") as scratch:
        for name in ("tests", "docs"):
            os.symlink(os.path.join(ROOT, name), os.path.join(scratch, name))
        for number, command, expected in sessions(text):
            count += 1
            code, lines = run(command, scratch)
            if code != 0:
                failures.append(f"README.md:{number}: `{command}` exited {code}:\n  "
                                + "\n  ".join(lines[-10:]))
                continue
            at = 0
            for want in expected:
                rx = pattern(want)
                while at < len(lines) and not rx.match(lines[at]):
                    at += 1
                if at == len(lines):
                    failures.append(f"README.md:{number}: `{command}` did not print\n"
                                    f"  {want}\n it printed:\n  " + "\n  ".join(lines[-10:]))
                    break
                at += 1
            print(f"check-readme: README.md:{number}: {command}: "
                  f"{'ok' if not failures or not failures[-1].startswith(f'README.md:{number}:') else 'DIFFERS'}")
    if count == 0:
        sys.exit("check-readme: no `$` command in a ```console block: nothing was checked")
    if failures:
        print("\n".join(failures), file=sys.stderr)
        sys.exit(1)
    print(f"check-readme: {count} commands, every printed line as the README says")


if __name__ == "__main__":
    main()
