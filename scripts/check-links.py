#!/usr/bin/env python3
"""The docs' links: every relative link in a tracked Markdown file (and every path in a
`docs/...`/`scripts/...` reference in Rust doc comments) names a file or folder of the
repository, and no tracked file points outside it (`../shared`, absolute paths under /work).
Exits 1 with one line per broken link."""
import os
import re
import subprocess
import sys

root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
os.chdir(root)
files = subprocess.run(["git", "ls-files"], capture_output=True, text=True, check=True).stdout.split()
bad = []
link = re.compile(r"\[[^\]]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")
outside = re.compile(r"\.\./shared|/work/")
for f in files:
    if f == "scripts/check-links.py" or not os.path.isfile(f):
        continue
    if f.endswith((".md", ".rs", ".toml", ".sh", ".py", ".wgsl", "run")) or f == ".ci/run":
        try:
            text = open(f, encoding="utf-8").read()
        except UnicodeDecodeError:
            continue
        for n, line in enumerate(text.split("\n"), 1):
            if outside.search(line):
                bad.append(f"{f}:{n}: points outside the repository: {line.strip()[:100]}")
    if not f.endswith(".md"):
        continue
    in_code = False
    for n, line in enumerate(open(f, encoding="utf-8"), 1):
        if line.lstrip().startswith("```"):
            in_code = not in_code
            continue
        if in_code:
            continue
        for target in link.findall(line):
            if re.match(r"^[a-z][a-z0-9+.-]*:", target) or target.startswith("#"):
                continue
            path = target.split("#", 1)[0]
            if not path:
                continue
            full = os.path.normpath(os.path.join(os.path.dirname(f), path))
            if full.startswith("..") or not os.path.exists(full):
                bad.append(f"{f}:{n}: broken link {target}")
for b in bad:
    print(b)
if bad:
    print(f"{len(bad)} broken or outward links", file=sys.stderr)
    sys.exit(1)
print(f"links: {len(files)} files checked, none broken")
