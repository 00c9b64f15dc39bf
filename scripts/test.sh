#!/usr/bin/env bash
# The test command: installs lavapipe and the X tools if needed, then runs every test of the
# workspace (GPU tests included, on lavapipe): each crate's unit tests, the one integration-test
# binary (tests/it), the examples, the benches as tests, and the doc tests (README included).
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/ensure-vulkan.sh
scripts/ensure-x11.sh
export WGPU_BACKEND="${WGPU_BACKEND:-vulkan}"
cargo test --workspace --all-targets --all-features "$@"
cargo test --workspace --doc --all-features
