#!/usr/bin/env bash
# touchfem in a browser: builds the page (the engine and the GPU pass compiled to wasm32 from
# crates/web, bound with wasm-bindgen, and the static files of web/) into DIR, then serves it on
# http://127.0.0.1:PORT/ until interrupted.
#
#   scripts/web.sh [--build-only] [--out DIR] [--port P]
#
# DIR defaults to target/web, P to 8080. The built folder is static: any web server can host
# it (docs/guide/web.md). Installs what the build needs when it is absent: the
# wasm32-unknown-unknown target (rustup) and wasm-bindgen-cli at the version Cargo.lock pins
# (cargo install, a few minutes once). Where a native `touchfem` program is at hand
# (release or debug under Cargo's target folder, or PATH), the bundled scenes' compliance caches are
# precomputed into DIR/cache so that the page starts without computing them; without one the
# page computes them itself. TOUCHFEM_WEB_NO_CACHES=1 skips them (the test command: its
# browser tests write their own).
set -euo pipefail
cd "$(dirname "$0")/.."
# Cargo's output folder (CARGO_TARGET_DIR where set).
tdir="${CARGO_TARGET_DIR:-target}"
out=target/web
port=8080
serve=1
usage() {
  echo "usage: scripts/web.sh [--build-only] [--out DIR] [--port P]" >&2
  exit 2
}
while [ $# -gt 0 ]; do
  case "$1" in
    --build-only) serve=0 ;;
    --out) [ $# -ge 2 ] || usage; out=$2; shift ;;
    --port) [ $# -ge 2 ] || usage; port=$2; shift ;;
    -h|--help) usage ;;
    *) echo "error: unknown argument '$1'" >&2; usage ;;
  esac
  shift
done
case "$port" in ''|*[!0-9]*) echo "error: --port '$port' is not a port number" >&2; exit 2 ;; esac

target=wasm32-unknown-unknown
sysroot=$(rustc --print sysroot)
if [ ! -d "$sysroot/lib/rustlib/$target/lib" ]; then
  command -v rustup >/dev/null 2>&1 || { echo "error: the $target target is missing and there is no rustup to add it" >&2; exit 1; }
  rustup target add "$target"
fi
want=$(awk '/^name = "wasm-bindgen"$/ { getline; gsub(/version = |"/, ""); print; exit }' Cargo.lock)
have=$(wasm-bindgen --version 2>/dev/null | awk '{ print $2 }' || true)
if [ "$have" != "$want" ]; then
  echo "installing wasm-bindgen-cli $want (the version Cargo.lock pins; once)…" >&2
  # Its own lock file first; where a registry mirror lacks a version it pins, the newest that
  # fits its requirements.
  cargo install --quiet --locked wasm-bindgen-cli --version "$want" 2>/dev/null \
    || cargo install --quiet wasm-bindgen-cli --version "$want"
fi

cargo build --quiet -p touchfem-web --target "$target" --profile web-release
mkdir -p "$out"
wasm-bindgen --target web --no-typescript --out-dir "$out" "$tdir/$target/web-release/touchfem_web.wasm"
cp web/index.html web/main.js web/worker.js "$out/"

# The compliance caches, where a native program can make them.
bin=""
for b in "$tdir/release/touchfem" "$tdir/debug/touchfem"; do
  if [ -x "$b" ]; then bin=$b; break; fi
done
if [ -z "$bin" ] && command -v touchfem >/dev/null 2>&1; then bin=$(command -v touchfem); fi
if [ "${TOUCHFEM_WEB_NO_CACHES:-0}" = 1 ]; then
  :
elif [ -n "$bin" ]; then
  mkdir -p "$out/cache"
  for s in fig1 fig2 palpate incision cube mouse phantom; do
    "$bin" precompute "$s" --out "$out/cache/$s.tfc" >/dev/null 2>&1 \
      || echo "note: no cache for $s (the page computes it)" >&2
  done
else
  echo "note: no native touchfem program (build one with 'cargo build --release --features app'); the page computes each scene's compliance itself" >&2
fi
size=$(gzip -9c "$out/touchfem_web_bg.wasm" | wc -c)
echo "built $out (wasm $(stat -c %s "$out/touchfem_web_bg.wasm") bytes, $size gzipped)"

if [ "$serve" = 1 ]; then
  echo "serving http://127.0.0.1:$port/ (Ctrl-C stops; in Chromium WebGPU may need --enable-unsafe-webgpu)"
  exec python3 -m http.server --bind 127.0.0.1 --directory "$out" "$port"
fi
