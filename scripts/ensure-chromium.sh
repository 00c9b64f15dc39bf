#!/usr/bin/env bash
# Makes sure the tools of scripts/web-driver.mjs are present: Debian's Chromium (package
# chromium, driven headless over the DevTools protocol) and Node.js >= 18 (package nodejs).
# Chromium renders WebGPU through its bundled SwiftShader, so no GPU or Vulkan driver is needed.
# Idempotent and silent when everything is there; needs root or sudo the first time.
set -euo pipefail
missing=()
command -v chromium >/dev/null 2>&1 || missing+=(chromium)
node_ok() {
  command -v node >/dev/null 2>&1 || return 1
  local major
  major="$(node -p 'process.versions.node.split(".")[0]' 2>/dev/null)" || return 1
  [ "${major:-0}" -ge 18 ]
}
node_ok || missing+=(nodejs)
if [ ${#missing[@]} -eq 0 ]; then
  exit 0
fi
SUDO=""
if [ "$(id -u)" != 0 ]; then
  if ! command -v sudo >/dev/null 2>&1; then
    echo "error: ${missing[*]} missing and not root (no sudo): install them with apt-get" >&2
    exit 1
  fi
  SUDO="sudo"
fi
if ! command -v apt-get >/dev/null 2>&1; then
  echo "error: ${missing[*]} missing and no apt-get here: install Chromium and Node.js >= 18" >&2
  exit 1
fi
echo "installing ${missing[*]} for scripts/web-driver.mjs..." >&2
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
$SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
if ! command -v chromium >/dev/null 2>&1; then
  echo "error: chromium is still not on PATH after apt-get install chromium" >&2
  exit 1
fi
if ! node_ok; then
  echo "error: node >= 18 is still missing (Debian's nodejs is $(node --version 2>/dev/null || echo absent))" >&2
  exit 1
fi
