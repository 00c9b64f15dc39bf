#!/usr/bin/env python3
"""Finds import circles between the modules (files) of each crate of the workspace.

Every `use crate::…`, `use super::…`, `use self::…` and every inline `crate::a::b` path is an
arrow from the file it is written in to the file that defines the module it names (the longest
prefix of the path that is a module). A module's `pub use` of its own children (the curated
list a `mod.rs` or `lib.rs` shows the outside) is not an arrow; every other re-export is. Prints each circle (a strongly connected component of
more than one file, or a file that imports itself) and exits 1 if there is any.

Usage: scripts/check-circles.py [CRATE_SRC_DIR ...]   (default: src and crates/*/src)
"""
import glob
import os
import re
import sys


def modules(src):
    """Module path (tuple) -> file, for one crate's src directory."""
    out = {}
    for path in glob.glob(os.path.join(src, "**", "*.rs"), recursive=True):
        rel = os.path.relpath(path, src)[:-3].split(os.sep)
        if rel in (["lib"], ["main"]):
            mod = ()
        elif rel[-1] == "mod":
            mod = tuple(rel[:-1])
        else:
            mod = tuple(rel)
        # Files under src/bin or examples-like folders that are not modules are still read.
        out.setdefault(mod, path)
    return out


def strip_comments(text):
    text = re.sub(r"/\*.*?\*/", "", text, flags=re.S)
    lines = []
    for line in text.split("\n"):
        # Drop line comments (also doc comments), keeping string contents approximately.
        i = line.find("//")
        lines.append(line if i < 0 else line[:i])
    return "\n".join(lines)


def expand(tree):
    """Expands a use tree like `a::{b, c::{d, e}}` into flat paths."""
    tree = tree.strip()
    i = tree.find("{")
    if i < 0:
        return [tree]
    head = tree[:i]
    body = tree[i + 1 : tree.rfind("}")]
    parts, depth, cur = [], 0, ""
    for ch in body:
        if ch == "," and depth == 0:
            parts.append(cur)
            cur = ""
            continue
        depth += ch == "{"
        depth -= ch == "}"
        cur += ch
    parts.append(cur)
    out = []
    for p in parts:
        if p.strip():
            for e in expand(p):
                out.append(head + e.strip())
    return out


def references(text):
    """Paths (as segment lists) a file uses: rooted at crate/super/self, or (in a `use`) at a
    child module's name. A unit-test module at the end of a file (`#[cfg(test)] mod …`, or
    `#[cfg(any(test, feature = "self-check"))] mod …`: the engine's checks, run from the
    integration binary) is left out: tests may use what they like."""
    text = strip_comments(text)
    m = re.search(r'#\[cfg\((?:test|any\(test,\s*feature\s*=\s*"self-check"\))\)\]\s*(pub(\(\w+\))?\s+)?mod\s+\w+\s*\{', text)
    if m:
        text = text[: m.start()]
    refs = []
    for m in re.finditer(r"\b(pub(?:\([\w:]+\))?\s+)?use\s+([^;]+);", text):
        reexport = m.group(1) is not None
        for p in expand(m.group(2)):
            p = re.sub(r"\s+as\s+\w+$", "", p.strip())
            segs = [s for s in p.split("::") if s]
            if segs and segs[0] in ("crate", "super", "self"):
                refs.append((segs, reexport))
            elif segs and re.fullmatch(r"[a-z_][a-z0-9_]*", segs[0]):
                refs.append((["self?"] + segs, reexport))
    for m in re.finditer(r"(?<![\w:])((?:crate|super|self)(?:::\w+)+)", text):
        refs.append((m.group(1).split("::"), False))
    return refs


def resolve(segs, here, mods, is_mod_file):
    """The module a path lands in, from the module `here` of a file."""
    root = segs[0]
    rest = segs[1:]
    if root == "self?":
        # A bare `use child::…`: a child module of this one, else an external crate.
        if here + (rest[0],) not in mods:
            return None
        root = "self"
    if root == "crate":
        base = ()
    elif root == "self":
        base = here
    else:  # super (possibly repeated)
        base = here
        while True:
            base = base[:-1]
            if rest and rest[0] == "super":
                rest = rest[1:]
                continue
            break
    best = base if base in mods else None
    cur = base
    for s in rest:
        cur = cur + (s,)
        if cur in mods:
            best = cur
        else:
            break
    return best


def circles(src):
    mods = modules(src)
    graph = {f: set() for f in mods.values()}
    for mod, f in mods.items():
        is_mod_file = f.endswith("mod.rs") or f.endswith("lib.rs") or f.endswith("main.rs")
        # In a non-mod file, `self` is the file's own module, `super` its parent.
        for segs, reexport in references(open(f, encoding="utf-8").read()):
            target = resolve(segs, mod, mods, is_mod_file)
            if target is None:
                continue
            # A module's curated `pub use` of its own children is its public face, not a
            # dependency: not an arrow.
            if reexport and target[: len(mod)] == mod and len(target) > len(mod):
                continue
            t = mods[target]
            if t != f:
                graph[f].add(t)
    # Tarjan's strongly connected components.
    index, low, stack, on, out = {}, {}, [], set(), []
    counter = [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
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
                out.append(sorted(comp))

    sys.setrecursionlimit(10000)
    for v in graph:
        if v not in index:
            visit(v)
    return out, graph


def main():
    srcs = sys.argv[1:] or (["src"] + sorted(glob.glob("crates/*/src")))
    found = 0
    for src in srcs:
        comps, graph = circles(src)
        for comp in comps:
            found += 1
            print(f"circle in {src}: {len(comp)} files")
            members = set(comp)
            for f in comp:
                for t in sorted(graph[f] & members):
                    print(f"  {f} -> {t}")
    if found:
        print(f"{found} import circle(s)")
        return 1
    print(f"no import circles in {', '.join(srcs)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
