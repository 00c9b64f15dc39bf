#!/usr/bin/env bash
# Environment variables and printing stay at the edge:
# - `std::env::var*` only in crates/core/src/options.rs, the gpu crate's options module
#   (crates/gpu/src/options.rs) and the app (crates/app, src/main.rs);
# - no println!/eprintln!/print!/eprint! in the libraries' code (crates/core, crates/gpu,
#   crates/lab): they log through the `log` facade, or return warnings as values. Unit-test
#   modules (after `#[cfg(test)]`, or the engine's `#[cfg(any(test, feature = "self-check"))]`
#   checks) may print.
set -euo pipefail
cd "$(dirname "$0")/.."
fail=0
strip_tests() { awk '/^#\[cfg\((test|any\(test, feature = "self-check"\))\)\]/{exit} {print FILENAME ":" FNR ":" $0}' "$1"; }
for f in $(find crates/core/src crates/gpu/src crates/lab/src -name '*.rs'); do
  case "$f" in
    crates/core/src/options.rs|crates/gpu/src/options.rs) ;;
    *) if strip_tests "$f" | grep -E 'std::env::var|env::var_os|env::var\(' | grep -v '^\S*:\s*//' ; then
         echo "  ^ an environment variable read outside the options modules" >&2; fail=1; fi ;;
  esac
  if strip_tests "$f" | grep -E '\b(e?println|e?print)!\(' | grep -vE ':\s*(//|\*)'; then
    echo "  ^ a library prints" >&2; fail=1
  fi
done
[ $fail = 0 ] && echo "environment and printing only at the edge"
exit $fail
