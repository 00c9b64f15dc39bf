#!/usr/bin/env bash
# Makes sure the tools of tests/view.rs are present: Xvfb (xvfb), xdotool, xwd (x11-apps) and
# ImageMagick's convert (imagemagick). Idempotent; needs root or sudo the first time.
set -euo pipefail
missing=()
command -v Xvfb >/dev/null 2>&1 || missing+=(xvfb)
command -v xdotool >/dev/null 2>&1 || missing+=(xdotool)
command -v xwd >/dev/null 2>&1 || missing+=(x11-apps)
# The real ImageMagick (a stand-in named convert elsewhere on PATH is not enough).
[ -x /usr/bin/convert ] || missing+=(imagemagick)
if [ ${#missing[@]} -eq 0 ]; then
  exit 0
fi
SUDO=""
if [ "$(id -u)" != 0 ]; then SUDO="sudo"; fi
echo "installing ${missing[*]} for tests/view.rs..." >&2
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
$SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
