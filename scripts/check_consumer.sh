#!/usr/bin/env bash
# Checks that a downstream CMake project can use orbitforge through
# find_package (after install) and through FetchContent.
set -euo pipefail
root=$(cd "$(dirname "$0")/.." && pwd)
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
cmake -S "$root" -B "$work/build" -DORBITFORGE_BUILD_TESTS=OFF -DORBITFORGE_BUILD_EXAMPLES=OFF \
  -DCMAKE_INSTALL_PREFIX="$work/prefix" >/dev/null
cmake --install "$work/build" >/dev/null
cmake -S "$root/tests/consumer" -B "$work/pkg" -DORBITFORGE_VIA=package -DCMAKE_PREFIX_PATH="$work/prefix" >/dev/null
cmake --build "$work/pkg" >/dev/null
"$work/pkg/consumer"
cmake -S "$root/tests/consumer" -B "$work/fetch" -DORBITFORGE_VIA=fetch -DORBITFORGE_SOURCE="$root" >/dev/null
cmake --build "$work/fetch" >/dev/null
"$work/fetch/consumer"
echo "check_consumer: find_package and FetchContent both work"
