#!/usr/bin/env bash
# Builds the examples and runs the main one on an input the project makes itself:
# fit_orbit on the synthetic recorded input (a partial arc of noisy, drifting
# estimated cameras), writing out/orbit.json and the orbit as COLMAP text and
# transforms.json.
set -euo pipefail
cd "$(dirname "$0")/.."
BUILD_DIR=${BUILD_DIR:-build}
OUT_DIR=${OUT_DIR:-out}
launcher=()
command -v ccache >/dev/null && launcher=(-DCMAKE_CXX_COMPILER_LAUNCHER=ccache)
generator=()
command -v ninja >/dev/null && generator=(-G Ninja)
cmake -S . -B "$BUILD_DIR" "${generator[@]}" -DCMAKE_BUILD_TYPE=Release "${launcher[@]}"
cmake --build "$BUILD_DIR" --parallel "$(nproc)" --target fit_orbit render_orbit make_prompt
mkdir -p "$OUT_DIR"
"$BUILD_DIR/examples/fit_orbit" --synthetic --out "$OUT_DIR/orbit.json" \
  --export-colmap "$OUT_DIR/orbit_colmap" --export-transforms "$OUT_DIR/orbit_transforms.json"
