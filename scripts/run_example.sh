#!/usr/bin/env bash
# Builds the examples and runs the main one, full_pipeline, on the input the
# project makes itself (a textured object on a ground plane seen from a partial
# arc with noisy, drifting estimated cameras; ground truth for every view): fit
# the canonical orbit, reconstruct G0 (deformable) + MedianGS, render R0,
# complete the gap (oracle), reconstruct G1, render R1, report. Outputs in
# out/pipeline (report.md, report.json, contact_sheet.png, final.ply, ...).
set -euo pipefail
cd "$(dirname "$0")/.."
BUILD_DIR=${BUILD_DIR:-build}
launcher=()
command -v ccache >/dev/null && launcher=(-DCMAKE_CXX_COMPILER_LAUNCHER=ccache)
generator=()
command -v ninja >/dev/null && generator=(-G Ninja)
cmake -S . -B "$BUILD_DIR" "${generator[@]}" -DCMAKE_BUILD_TYPE=Release "${launcher[@]}"
cmake --build "$BUILD_DIR" --parallel "$(nproc)" --target full_pipeline fit_orbit render_orbit reconstruct make_prompt
"$BUILD_DIR/examples/full_pipeline"
