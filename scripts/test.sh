#!/usr/bin/env bash
# The test command: installs lavapipe and the X tools if needed, then runs every test of the
# workspace (GPU tests included, on lavapipe): the GPU and web crates' unit tests, the one
# integration-test binary (tests/it, which also runs the examples and the engine's unit
# checks), the doc tests (README and the embedding guide included), and the web page in a
# headless Chromium. The criterion benches (their own package, benches/) are built by
# `.ci/run`'s clippy, not here.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/ensure-vulkan.sh
scripts/ensure-x11.sh
export WGPU_BACKEND="${WGPU_BACKEND:-vulkan}"
export CARGO_INCREMENTAL="${CARGO_INCREMENTAL:-0}"
# The web page for the browser tests (tests/it/web.rs): Chromium and Node from Debian's
# packages, the page built for wasm32 (scripts/web.sh installs the target and wasm-bindgen-cli
# when absent). Where that cannot be had the browser tests say they are skipped.
# TOUCHFEM_SKIP_WEB=1 leaves the browser part out (on a machine without Chromium or wasm32).
if [ "${TOUCHFEM_SKIP_WEB:-0}" = 1 ]; then
  echo "note: TOUCHFEM_SKIP_WEB=1: the browser tests are SKIPPED" >&2
elif scripts/ensure-chromium.sh && TOUCHFEM_WEB_NO_CACHES=1 scripts/web.sh --build-only --out target/web-test; then
  export TOUCHFEM_WEB_DIR="$PWD/target/web-test"
else
  echo "note: the web page could not be built; the browser tests are SKIPPED" >&2
fi
# Without target flags, `cargo test` runs the doc tests too. On a machine with fewer than
# three cores the tests run three at a time: some of them wait on real time (the UDP and
# window loops, the browser) and would leave a core idle
# (docs/measurements/2026-12-06-cold-test.md).
[ "$(nproc)" -ge 3 ] || export RUST_TEST_THREADS="${RUST_TEST_THREADS:-3}"
cargo test --workspace --all-features "$@"
