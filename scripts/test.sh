#!/usr/bin/env bash
# The test command: installs lavapipe if needed, then runs every test (GPU tests included) on it.
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/ensure-vulkan.sh
scripts/ensure-x11.sh
export WGPU_BACKEND="${WGPU_BACKEND:-vulkan}"
cargo test --all-targets "$@"
cargo test --doc
