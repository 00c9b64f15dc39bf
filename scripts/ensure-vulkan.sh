#!/usr/bin/env bash
# Makes sure a Vulkan driver is present: Mesa's lavapipe (software Vulkan, Debian package
# mesa-vulkan-drivers) when nothing else is installed. Idempotent; needs root or sudo the
# first time.
set -euo pipefail
if ls /usr/share/vulkan/icd.d/*.json >/dev/null 2>&1 && ldconfig -p 2>/dev/null | grep -q libvulkan.so.1; then
  exit 0
fi
SUDO=""
if [ "$(id -u)" != 0 ]; then SUDO="sudo"; fi
echo "installing Mesa's lavapipe (mesa-vulkan-drivers, libvulkan1)..." >&2
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
$SUDO apt-get install -y -qq --no-install-recommends mesa-vulkan-drivers libvulkan1 >/dev/null
ls /usr/share/vulkan/icd.d/*.json >&2
