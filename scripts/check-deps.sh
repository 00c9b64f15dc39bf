#!/usr/bin/env bash
# The workspace's dependency rules, checked on `cargo tree` (normal dependencies):
# - the engine (touchfem-core) pulls in none of wgpu, naga, winit, clap, plotters, indicatif,
#   ab_glyph;
# - the GPU crate (touchfem-gpu) none of winit, clap, plotters, indicatif;
# - the `touchfem` crate with its default features none of winit, clap, plotters, indicatif.
# Prints each crate's count of crates and exits 1 on a broken rule.
set -euo pipefail
cd "$(dirname "$0")/.."
fail=0
check() { # package, features args, forbidden...
  local pkg=$1 feats=$2; shift 2
  local tree
  tree=$(cargo tree -p "$pkg" $feats -e normal --prefix none --format '{p}' | sed 's/ (.*//' | sort -u)
  echo "$pkg${feats:+ $feats}: $(echo "$tree" | wc -l) crates"
  for bad in "$@"; do
    if echo "$tree" | grep -qE "^$bad v"; then
      echo "  rule broken: $pkg depends on $bad" >&2
      fail=1
    fi
  done
}
check touchfem-core "" wgpu naga winit clap plotters indicatif ab_glyph
check touchfem-gpu "" winit clap plotters indicatif
check touchfem "" winit clap plotters indicatif
exit $fail
