#!/usr/bin/env bash
# Installs orbitforge's build dependencies from Debian 12's packages.
set -euo pipefail
packages=(build-essential cmake ninja-build ccache pkg-config
  libeigen3-dev libxsimd-dev libstb-dev nlohmann-json3-dev zlib1g-dev libsqlite3-dev
  libcli11-dev catch2 libbenchmark-dev python3-matplotlib clang libclang-rt-14-dev
  ffmpeg colmap)  # full_pipeline --video / --images and their tests run these two programs
missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -eq 0 ]; then
  echo "setup: all dependencies present"
  exit 0
fi
SUDO=""
[ "$(id -u)" -eq 0 ] || SUDO="sudo"
echo "setup: installing ${missing[*]}"
$SUDO apt-get update -qq
DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
