#!/usr/bin/env python3
"""The code's shape, checked: no file-level import circle, no file over 900 lines, no function
over 120 lines.

usage: check-structure.py [--list] [--skip DIR ...] TREE [TREE ...]

TREE is a crate's source folder (`src`, `hal-sim/src`, `pil/src`). Every `.rs` file in it is
read as text (comments, strings and `#[cfg(test)]` modules left out):
- an edge a.rs -> b.rs is a path in a.rs (`use`, or inline `crate::`, `super::`, `self::`) that
  names an item of b.rs's module (a parent's `mod child;` and its relative `use child::…`
  are the module tree, not edges; a child's `super::` path to its parent is an edge). A
  circle is a set of files that reach each other;
- a file's length is its lines up to its first `#[cfg(test)]` (the tests after it are not
  counted);
- a function's length is its lines from `fn` to its closing brace, tests left out.
`--skip DIR` (relative to the tree) leaves a folder out of the function and circle checks
(for work owned elsewhere); `--list` prints every function over the limit. Prints one line
per tree and exits 1 if any tree falls short.
"""
import os
import re
import sys

MAX_FILE_LINES = 900
MAX_FN_LINES = 120


def strip(text):
    """The text with comments, string and char literals blanked (newlines kept)."""
    out, i, n = [], 0, len(text)
    while i < n:
        c = text[i]
        if text.startswith("//", i):
            j = text.find("\n", i)
            j = n if j < 0 else j
            i = j
            continue
        if text.startswith("/*", i):
            depth, j = 1, i + 2
            while j < n and depth:
                if text.startswith("/*", j):
                    depth, j = depth + 1, j + 2
                elif text.startswith("*/", j):
                    depth, j = depth - 1, j + 2
                else:
                    j += 1
            out.append("\n" * text.count("\n", i, j))
            i = j
            continue
        m = re.match(r'b?r(#*)"', text[i:i + 40])
        if m and (i == 0 or not (text[i - 1].isalnum() or text[i - 1] == "_")):
            end = '"' + m.group(1)
            j = text.find(end, i + len(m.group(0)))
            j = n if j < 0 else j + len(end)
            out.append('""' + "\n" * text.count("\n", i, j))
            i = j
            continue
        if c == '"':
            j = i + 1
            while j < n and text[j] != '"':
                j += 2 if text[j] == "\\" else 1
            out.append('""' + "\n" * text.count("\n", i, j))
            i = j + 1
            continue
        if c == "'":
            m = re.match(r"'(\\.[^']*|[^\\'])'", text[i:i + 12])
            if m:
                out.append("' '")
                i += len(m.group(0))
                continue
        out.append(c)
        i += 1
    return "".join(out)


def without_tests(code):
    """Blanks every item under `#[cfg(test)]` (a `mod tests { … }` or a single item)."""
    out = list(code)
    for m in re.finditer(r"#\[cfg\(test\)\]", code):
        j = code.find("{", m.end())
        semi = code.find(";", m.end())
        if j < 0 or (0 <= semi < j):
            continue
        depth, k = 0, j
        while k < len(code):
            depth += (code[k] == "{") - (code[k] == "}")
            if depth == 0:
                break
            k += 1
        for x in range(m.start(), min(k + 1, len(code))):
            if out[x] != "\n":
                out[x] = " "
    return "".join(out)


def functions(code):
    """(name, first line, lines) of every function with a body."""
    found = []
    for m in re.finditer(r"\bfn\s+([A-Za-z_][A-Za-z0-9_]*)", code):
        # The body's brace: the first `{` after the signature, unless a `;` ends it first.
        depth, k = 0, m.end()
        while k < len(code):
            ch = code[k]
            if ch in "([<":
                depth += 1
            elif ch in ")]>" and depth > 0 and not (ch == ">" and code[k - 1] == "-"):
                depth -= 1
            elif ch == ";" and depth == 0:
                k = -1
                break
            elif ch == "{" and depth == 0:
                break
            k += 1
        if k < 0 or k >= len(code):
            continue
        depth, e = 0, k
        while e < len(code):
            depth += (code[e] == "{") - (code[e] == "}")
            if depth == 0:
                break
            e += 1
        first = code.count("\n", 0, m.start()) + 1
        last = code.count("\n", 0, e) + 1
        found.append((m.group(1), first, last - first + 1))
    return found


def file_module(tree, path):
    rel = os.path.relpath(path, tree)[:-3].split(os.sep)
    if rel[-1] in ("mod", "lib", "main"):
        rel = rel[:-1]
    return tuple(rel)


def expand(tree):
    """`a::{b, c::{d, e}}` -> ['a::b', 'a::c::d', 'a::c::e']"""
    tree = tree.strip()
    i = tree.find("{")
    if i < 0:
        return [tree]
    head, body = tree[:i], tree[i + 1:tree.rfind("}")]
    parts, depth, cur = [], 0, ""
    for ch in body:
        if ch == "," and depth == 0:
            parts.append(cur)
            cur = ""
            continue
        depth += (ch == "{") - (ch == "}")
        cur += ch
    parts.append(cur)
    return [x for p in parts if p.strip() for x in expand(head + p.strip())]


def circles(tree, files, code):
    by_mod = {file_module(tree, f): f for f in files}
    graph = {}
    for f in files:
        me = file_module(tree, f)
        text = code[f]
        paths = []
        for u in re.findall(r"\buse\s+([^;]+);", text):
            paths += expand(re.sub(r"\s+as\s+\w+", "", u))
        paths += re.findall(r"\b((?:crate|super|self)(?:::[A-Za-z_][A-Za-z0-9_]*)+)", text)
        deps = set()
        for p in paths:
            seg = [x for x in p.replace(" ", "").split("::") if x]
            if not seg:
                continue
            if seg[0] == "crate":
                base, seg = (), seg[1:]
            elif seg[0] in ("super", "self"):
                base = me
                if seg[0] == "self":
                    seg = seg[1:]
                while seg and seg[0] == "super":
                    base, seg = base[:-1], seg[1:]
            else:
                continue
            full = base + tuple(seg)
            for k in range(len(full), -1, -1):
                t = by_mod.get(full[:k])
                if t:
                    if t != f:
                        deps.add(t)
                    break
        graph[f] = deps
    index, low, on, stack, out, n = {}, {}, set(), [], [], [0]
    sys.setrecursionlimit(10000)

    def strong(v):
        index[v] = low[v] = n[0]
        n[0] += 1
        stack.append(v)
        on.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                strong(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(os.path.relpath(c, tree) for c in comp))

    for v in sorted(graph):
        if v not in index:
            strong(v)
    return out


def main(argv):
    listing = "--list" in argv
    argv = [a for a in argv if a != "--list"]
    skips, trees = [], []
    it = iter(argv)
    for a in it:
        if a == "--skip":
            skips.append(next(it).rstrip("/"))
        else:
            trees.append(a)
    if not trees:
        print(__doc__.strip().splitlines()[2], file=sys.stderr)
        return 2
    bad = False
    for tree in trees:
        files = sorted(os.path.join(dp, f) for dp, _, fs in os.walk(tree) for f in fs if f.endswith(".rs"))
        code = {f: without_tests(strip(open(f, encoding="utf-8").read())) for f in files}
        skipped = lambda f: any(os.path.relpath(f, tree).startswith(s + os.sep) for s in skips)
        lines = []
        for f in files:
            n = 0
            for line in open(f, encoding="utf-8"):
                if line.strip().startswith("#[cfg(test)]"):
                    break
                n += 1
            lines.append((n, os.path.relpath(f, tree)))
        long_files = [(n, f) for n, f in lines if n > MAX_FILE_LINES]
        fns = [(ln, os.path.relpath(f, tree), name, first)
               for f in files if not skipped(f) for name, first, ln in functions(code[f])]
        long_fns = sorted((x for x in fns if x[0] > MAX_FN_LINES), reverse=True)
        circ = circles(tree, [f for f in files if not skipped(f)], code)
        longest_fn = max(fns, default=(0, "-", "-", 0))
        longest_file = max(lines, default=(0, "-"))
        note = f" (leaving out {', '.join(skips)})" if skips else ""
        print(f"{tree}{note}: file-level circles {len(circ)}"
              + (f" e.g. {', '.join(circ[0])}" if circ else "")
              + f"; longest file {longest_file[1]} {longest_file[0]} lines, over {MAX_FILE_LINES}: {len(long_files)}"
              + f"; longest function {longest_fn[1]}::{longest_fn[2]} {longest_fn[0]} lines,"
              + f" over {MAX_FN_LINES}: {len(long_fns)}")
        if listing:
            for c in circ:
                print("  circle: " + ", ".join(c))
            for n, f in long_files:
                print(f"  file {f}: {n} lines")
            for ln, f, name, first in long_fns:
                print(f"  fn {f}:{first} {name}: {ln} lines")
        bad = bad or bool(circ or long_files or long_fns)
    print("check-structure: " + ("falls short" if bad else "holds"))
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
