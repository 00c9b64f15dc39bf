#!/usr/bin/env bash
# The test command: installs lavapipe and the X tools if needed, then runs every test of the
# workspace (GPU tests included, on lavapipe): each crate's unit tests, the one integration-test
# binary (tests/it, which also runs the examples), and the doc tests (README and the embedding
# guide included). The criterion benches are built by `.ci/run`'s clippy, not here.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/ensure-vulkan.sh
scripts/ensure-x11.sh
export WGPU_BACKEND="${WGPU_BACKEND:-vulkan}"
export CARGO_INCREMENTAL="${CARGO_INCREMENTAL:-0}"
# Without target flags, `cargo test` runs the doc tests too.
cargo test --workspace --all-features "$@"
