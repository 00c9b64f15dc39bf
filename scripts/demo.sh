#!/usr/bin/env bash
# The main job: the bundled scenes headless, frames and the paper's Table 2 (see README).
set -euo pipefail
cd "$(dirname "$0")/.."
scripts/ensure-vulkan.sh
export WGPU_BACKEND="${WGPU_BACKEND:-vulkan}"
cargo run --release --features app --bin touchfem -- demo "$@"
