#!/usr/bin/env bash
# Builds and runs the test suite. BUILD_DIR and extra CMake arguments may be given:
#   scripts/test.sh                      # build/ , Release
#   BUILD_DIR=build-asan scripts/test.sh -DORBITFORGE_SANITIZE=address,undefined
# TEST_TARGETS (space-separated) builds only those targets, and TEST_REGEX runs
# only the ctest entries it matches (both default to everything).
set -euo pipefail
cd "$(dirname "$0")/.."
BUILD_DIR=${BUILD_DIR:-build}
BUILD_TYPE=${BUILD_TYPE:-Release}
launcher=()
command -v ccache >/dev/null && launcher=(-DCMAKE_CXX_COMPILER_LAUNCHER=ccache)
generator=()
command -v ninja >/dev/null && generator=(-G Ninja)
cmake -S . -B "$BUILD_DIR" "${generator[@]}" -DCMAKE_BUILD_TYPE="$BUILD_TYPE" "${launcher[@]}" -DORBITFORGE_BUILD_TESTS=ON "$@"
targets=()
for t in ${TEST_TARGETS:-}; do targets+=(--target "$t"); done
cmake --build "$BUILD_DIR" --parallel "$(nproc)" "${targets[@]}"
# Tests in parallel: the longest then overlaps all the others.
select=()
[ -n "${TEST_REGEX:-}" ] && select=(--tests-regex "$TEST_REGEX")
ctest --test-dir "$BUILD_DIR" --output-on-failure --timeout 1500 --parallel "$(nproc)" "${select[@]}"
