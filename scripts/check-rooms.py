#!/usr/bin/env python3
"""Checks that every import in the engine (crates/core/src) points down the order of its rooms.

The rooms are the engine's root modules, bottom first (ARCHITECTURE.md, "Rooms of the
engine"). Every `use crate::…` and every inline `crate::a::b` path of a file in room R (its first
module under src) must land in R or a room below it. A path to
a name that the root re-exports (`crate::Error`, `crate::Mesh`) lands in the room that defines
it. Comments (doc links included) and a file's unit tests (`#[cfg(test)] mod …` at its end) are
not imports. Prints each upward import and their count; exits 1 if there is any that is not in
ALLOWED. Also checks that no library file (crates/*/src, src) is over 1,200 lines.

Usage: scripts/check-rooms.py
"""
import glob
import importlib.util
import os
import re
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
SRC = os.path.join(HERE, "..", "crates", "core", "src")

# Bottom to top. Keep in step with ARCHITECTURE.md and crates/core/src/lib.rs.
ORDER = [
    "limits",
    "options",
    "threads",
    "mesh",
    "fem",
    "compliance",
    "cache",
    "contact",
    "devices",
    "error",
    "precompute",
    "cut",
    "scene",
    "haptic",
    "runtime",
    # Hidden, only under the `self-check` feature: the registry of every room's unit checks,
    # so above them all.
    "self_check",
]

# Root files that belong to a room without being its module.
MEMBERS = {}

# Upward imports tolerated, as (file relative to src, room it reaches): none.
ALLOWED = set()


def load_circles():
    spec = importlib.util.spec_from_file_location(
        "check_circles", os.path.join(HERE, "check-circles.py")
    )
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def room_of(mod):
    if not mod:
        return None
    return MEMBERS.get(mod[0], mod[0])


def root_reexports(cc, lib):
    """Name re-exported by lib.rs -> the room it comes from."""
    text = cc.strip_comments(open(lib, encoding="utf-8").read())
    out = {}
    for m in re.finditer(r"\bpub\s+use\s+([^;]+);", text):
        for p in cc.expand(m.group(1)):
            segs = [s for s in re.sub(r"\s+as\s+\w+$", "", p.strip()).split("::") if s]
            if segs and segs[0] == "crate":
                segs = segs[1:]
            if len(segs) >= 2:
                out[segs[-1]] = room_of((segs[0],))
    return out


def main():
    cc = load_circles()
    src = os.path.normpath(SRC)
    mods = cc.modules(src)
    reexports = root_reexports(cc, os.path.join(src, "lib.rs"))
    rank = {r: i for i, r in enumerate(ORDER)}
    problems = []
    unknown = set()
    for mod, f in sorted(mods.items()):
        here = room_of(mod)
        if here is None:
            continue
        if here not in rank:
            unknown.add(here)
            continue
        rel = os.path.relpath(f, src)
        is_mod_file = f.endswith("mod.rs")
        seen = set()
        for segs, _ in cc.references(open(f, encoding="utf-8").read()):
            target = cc.resolve(segs, mod, mods, is_mod_file)
            if target is None:
                continue
            if target == ():
                # `crate::Name`: the room of a re-exported name, else the root itself.
                rest = [s for s in segs if s not in ("crate", "super", "self")]
                there = reexports.get(rest[0]) if rest else None
                if there is None:
                    continue
            else:
                there = room_of(target)
            if there == here or there not in rank:
                continue
            if rank[there] > rank[here] and (rel, there) not in seen:
                seen.add((rel, there))
                problems.append((rel, here, there, "::".join(segs)))
    if unknown:
        print(f"rooms not in the order of scripts/check-rooms.py: {', '.join(sorted(unknown))}")
    bad = 0
    for rel, here, there, path in problems:
        allowed = (rel, there) in ALLOWED
        bad += not allowed
        note = " (allowed)" if allowed else ""
        print(f"  up: {rel} ({here}) -> {path} ({there}){note}")
    print(f"{len(problems)} upward import(s) in crates/core/src ({bad} not allowed)")
    print("rooms, bottom first: " + " < ".join(ORDER))
    long_files = too_long()
    return 1 if bad or unknown or long_files else 0


# No library file (crates/*/src, src) over this many lines.
MAX_LINES = 1200


def too_long():
    """Prints each library file over MAX_LINES lines and the longest one; returns their count."""
    root = os.path.join(HERE, "..")
    files = glob.glob(os.path.join(root, "crates", "*", "src", "**", "*.rs"), recursive=True)
    files += glob.glob(os.path.join(root, "src", "**", "*.rs"), recursive=True)
    sizes = []
    for f in files:
        with open(f, encoding="utf-8") as fh:
            sizes.append((sum(1 for _ in fh), os.path.relpath(f, root)))
    sizes.sort(reverse=True)
    over = [(n, f) for n, f in sizes if n > MAX_LINES]
    for n, f in over:
        print(f"  too long: {f} has {n} lines (at most {MAX_LINES})")
    if sizes:
        print(f"longest library file: {sizes[0][1]} ({sizes[0][0]} lines); {len(over)} over {MAX_LINES}")
    return len(over)


if __name__ == "__main__":
    sys.exit(main())
