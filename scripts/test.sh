#!/usr/bin/env bash
# Builds and runs the test suite. BUILD_DIR and extra CMake arguments may be given:
#   scripts/test.sh                      # build/ , Release
#   BUILD_DIR=build-asan scripts/test.sh -DORBITFORGE_SANITIZE=address,undefined
set -euo pipefail
cd "$(dirname "$0")/.."
BUILD_DIR=${BUILD_DIR:-build}
BUILD_TYPE=${BUILD_TYPE:-Release}
launcher=()
command -v ccache >/dev/null && launcher=(-DCMAKE_CXX_COMPILER_LAUNCHER=ccache)
generator=()
command -v ninja >/dev/null && generator=(-G Ninja)
cmake -S . -B "$BUILD_DIR" "${generator[@]}" -DCMAKE_BUILD_TYPE="$BUILD_TYPE" "${launcher[@]}" -DORBITFORGE_BUILD_TESTS=ON "$@"
cmake --build "$BUILD_DIR" --parallel "$(nproc)"
# Tests in parallel: the longest (the trainer under the sanitizers, ~3 min) then
# overlaps all the others.
ctest --test-dir "$BUILD_DIR" --output-on-failure --timeout 1500 --parallel "$(nproc)"
