#!/usr/bin/env python3
"""Runs the README's tour and checks that what it prints is what the tools print.

Every ```console block of README.md is a session: a line `$ CMD` is run, the lines after it
(up to the next `$` line or the block's end) are what it must print, in order; other lines
may come between them (cargo's progress, for instance). In an expected line `…` stands for
anything (wall-clock figures). `fpc-sim` commands run the release build
(`target/release/fpc-sim`) in a scratch directory that sees the repository's `tests/` and
`docs/` (and `hal-sim/` for its reference model, `target/` for the firmware's ELF), so the tour writes nothing into the checkout;
other commands (`cargo fw`, `bash scripts/…`) run in the repository.

A document that shows a bench session declares the recording its `fpc-sim link` commands are
played back from, in a comment line of its own:

    <!-- check-readme: link --replay docs/examples/bench-session -->

Each `fpc-sim link …` command of that document then runs with `--replay DIR` appended (the
printed `earlier answer: …` lines are other lines, allowed between the expected ones).

Usage: python3 scripts/check-readme.py [FILE...]   (default README.md; exit 1 naming every
line that differs)
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


def link_replay(text):
    """The recording a document's `fpc-sim link` commands are played back from, if declared."""
    found = re.search(r"^<!-- check-readme: link --replay (\S+) -->$", text, re.MULTILINE)
    return found.group(1) if found else None


def pattern(expected):
    parts = [re.escape(p) for p in expected.split("…")]
    return re.compile("^" + ".*?".join(parts) + "$")


def run(command, scratch, replay=None):
    words = shlex.split(command, comments=True)
    if replay and words[:2] == ["fpc-sim", "link"]:
        words += ["--replay", replay]
    if words[0] == "fpc-sim":
        words[0] = os.path.join(ROOT, "target", "release", "fpc-sim")
        cwd = scratch
    else:
        cwd = ROOT
    done = subprocess.run(words, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                          text=True, timeout=900)
    return done.returncode, done.stdout.splitlines()


def check(label, text, scratch, failures):
    """Runs every session of one document; returns how many commands it ran."""
    count = 0
    replay = link_replay(text)
    for number, command, expected in sessions(text):
        count += 1
        where = f"{label}:{number}"
        code, lines = run(command, scratch, replay)
        problem = None
        if code != 0:
            problem = f"`{command}` exited {code}:\n  " + "\n  ".join(lines[-10:])
        else:
            at = 0
            for want in expected:
                rx = pattern(want)
                while at < len(lines) and not rx.match(lines[at]):
                    at += 1
                if at == len(lines):
                    problem = (f"`{command}` did not print\n  {want}\n it printed:\n  "
                               + "\n  ".join(lines[-10:]))
                    break
                at += 1
        print(f"check-readme: {where}: {command}: {'DIFFERS' if problem else 'ok'}")
        if problem:
            failures.append(f"{where}: {problem}")
    return count


def main():
    files = sys.argv[1:] or ["README.md"]
    binary = os.path.join(ROOT, "target", "release", "fpc-sim")
    if not os.path.exists(binary):
        sys.exit(f"check-readme: {binary} is missing (cargo build --release -p hal-sim)")
    failures = []
    count = 0
    for name in files:
        path = name if os.path.isabs(name) else os.path.join(ROOT, name)
        with open(path, encoding="utf-8") as f:
            text = f.read()
        # Each document's sessions in a scratch directory of their own, as a reader would
        # run them: two documents may write the same output folder.
        with tempfile.TemporaryDirectory(prefix="fpc-readme-") as scratch:
            for linked in ("tests", "docs", "target", "hal-sim"):
                os.symlink(os.path.join(ROOT, linked), os.path.join(scratch, linked))
            ran = check(os.path.relpath(path, ROOT), text, scratch, failures)
        if ran == 0:
            failures.append(f"{name}: no `$` command in a ```console block: nothing checked")
        count += ran
    if failures:
        print("\n".join(failures), file=sys.stderr)
        sys.exit(1)
    print(f"check-readme: {count} commands, every printed line as the documents say")


if __name__ == "__main__":
    main()
