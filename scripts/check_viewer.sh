#!/usr/bin/env bash
# Ecosystem check: a scene orbitforge reconstructed opens in a web Gaussian-splat viewer.
#
#   scripts/check_viewer.sh    # BUILD_DIR=build by default; VIEWER_CHECK_OUT=DIR keeps the pictures
#                              # (DIR/a-final-ply/side_by_side.png is docs/viewer_check.png)
#
# Steps: install the viewer (Spark on three.js) and playwright-core from npm into a
# temporary prefix (pinned by scripts/viewer/package-lock.json); build full_pipeline,
# render_orbit and ply_tool; run the pipeline small on its synthetic input (final.ply +
# final.spz + orbit.json: a real reconstruction, ~25 s of CPU time); render two orbit
# cameras with render_orbit; draw the same cameras in headless Chromium with software
# WebGL (SwiftShader) through scripts/viewer/index.html (final.ply at both cameras,
# final.spz at the first); pass when the PSNR of each of the viewer's pictures
# against ours is at least VIEWER_MIN_PSNR (25 dB).
#
# Outside CI (CI unset or "false") it exits 0 with "skipped: ..." when node/npm or
# chromium are missing, the npm registry cannot be reached or Chromium cannot start;
# with CI=true it installs chromium (and node/npm) with apt-get when missing and fails
# instead of skipping.
set -euo pipefail
cd "$(dirname "$0")/.."
start=$(date +%s)
BUILD_DIR=${BUILD_DIR:-build}
MIN_PSNR=${VIEWER_MIN_PSNR:-25}
CHROMIUM=${CHROMIUM:-/usr/bin/chromium}
export CHROMIUM

CHECK_NAME=viewer
# shellcheck source=scripts/check_lib.sh
source scripts/check_lib.sh  # the working folder is the repository root here

need_node
if [ ! -x "$CHROMIUM" ]; then
  if in_ci && [ "$CHROMIUM" = /usr/bin/chromium ]; then apt_install chromium; else
    skip "$CHROMIUM not found (Debian: apt-get install chromium)"
  fi
fi

WORK=$(mktemp -d "${TMPDIR:-/tmp}/orbitforge-viewer.XXXXXX")
trap 'rm -rf "$WORK"' EXIT

echo "== installing the viewer (scripts/viewer/package-lock.json) into $WORK/npm"
mkdir -p "$WORK/npm"
cp scripts/viewer/package.json scripts/viewer/package-lock.json "$WORK/npm/"
if ! (cd "$WORK/npm" && PLAYWRIGHT_SKIP_BROWSER_DOWNLOAD=1 timeout 600 npm ci --no-audit --no-fund >"$WORK/npm.log" 2>&1); then
  tail -5 "$WORK/npm.log" || true
  skip "npm registry not reachable (npm ci of scripts/viewer failed)"
fi
node -e 'for (const p of ["three", "@sparkjsdev/spark", "playwright-core"])
  console.log(`installed: ${p} ${require(process.argv[1] + "/node_modules/" + p + "/package.json").version}`)' "$WORK/npm"

echo "== building full_pipeline, render_orbit and ply_tool in $BUILD_DIR"
launcher=()
command -v ccache >/dev/null && launcher=(-DCMAKE_CXX_COMPILER_LAUNCHER=ccache)
generator=()
command -v ninja >/dev/null && generator=(-G Ninja)
cmake -S . -B "$BUILD_DIR" "${generator[@]}" "${launcher[@]}" -DCMAKE_BUILD_TYPE=Release >"$WORK/cmake.log" 2>&1 ||
  { cat "$WORK/cmake.log"; exit 1; }
cmake --build "$BUILD_DIR" --parallel "$(nproc)" --target full_pipeline render_orbit ply_tool >"$WORK/build.log" 2>&1 ||
  { tail -30 "$WORK/build.log"; exit 1; }
built=$(date +%s)

# The scene: the whole method on the synthetic input, at a size that fits CI.
PIPE="$WORK/pipeline"
PIPELINE_ARGS=(--width 64 --height 64 --views 37 --iters 300 --median-samples 16 --background 0,0,0 --quiet)
echo "== full_pipeline ${PIPELINE_ARGS[*]}"
"$BUILD_DIR/examples/full_pipeline" "${PIPELINE_ARGS[@]}" --out "$PIPE" >"$WORK/pipeline.log" 2>&1 ||
  { tail -30 "$WORK/pipeline.log"; echo "FAIL: full_pipeline"; exit 1; }
scened=$(date +%s)
"$BUILD_DIR/examples/ply_tool" info "$PIPE/final.ply" |
  node -e 'const i = JSON.parse(require("fs").readFileSync(0, "utf8"));
    console.log(`final.ply: ${i.count} Gaussians, SH degree ${i.sh_degree}`)'

# Two orbit cameras, a third and two thirds of the way round, at twice the training
# resolution (fx, fy, cx, cy and the size doubled: more pixels per splat to compare).
# The first is drawn on the scene's own black background, the second on grey, which
# also checks how each renderer composites onto the background.
SCALE=${VIEWER_CAMERA_SCALE:-2}
node -e '
const fs = require("fs");
const [orbitFile, dir, scaleText] = process.argv.slice(1);
const orbit = JSON.parse(fs.readFileSync(orbitFile, "utf8"));
const n = orbit.cameras.length, s = Number(scaleText);
if (!(s > 0)) { console.error(`VIEWER_CAMERA_SCALE must be positive, got ${scaleText}`); process.exit(1); }
for (const [name, i] of [["a", Math.floor(n / 3)], ["b", Math.floor((2 * n) / 3)]]) {
  const c = { ...orbit.cameras[i] };
  for (const k of ["width", "height"]) c[k] = Math.round(c[k] * s);
  for (const k of ["fx", "fy", "cx", "cy"]) c[k] *= s;
  fs.writeFileSync(`${dir}/cam_${name}.json`, JSON.stringify(c));
  console.log(`camera ${name}: orbit view ${i} of ${n} (azimuth ${c.azimuth_deg.toFixed(1)} deg), ${c.width}x${c.height}`);
}
' "$PIPE/orbit.json" "$PIPE" "$SCALE"

echo "== drawing final.ply in headless Chromium ($CHROMIUM) with the viewer"
OUT=${VIEWER_CHECK_OUT:-$WORK/check}
status=0
# final.spz (the same scene, quantised for the web) is drawn at camera a too, against
# the same render_orbit picture of final.ply.
[ -f "$PIPE/final.spz" ] || { echo "FAIL: full_pipeline wrote no final.spz"; exit 1; }
for view in a:0,0,0:final.ply a:0,0,0:final.spz b:0.5,0.5,0.5:final.ply; do
  IFS=: read -r name bg scene <<<"$view"
  [ -f "$PIPE/ours_$name/00000.png" ] ||
    "$BUILD_DIR/examples/render_orbit" --ply "$PIPE/final.ply" --camera "$PIPE/cam_$name.json" --background "$bg" \
      --out "$PIPE/ours_$name" >/dev/null
  echo "-- $scene, camera $name, background $bg"
  node scripts/viewer/check.mjs --modules "$WORK/npm/node_modules" --data "$PIPE" --ply "$scene" \
    --camera "cam_$name.json" --ref "ours_$name/00000.png" --bg "$bg" --min-psnr "$MIN_PSNR" --scale 1 \
    --out "$OUT/$name-${scene/./-}" || { status=$?; break; }
done
end=$(date +%s)
echo "viewer check: $((end - start)) s (install + build $((built - start)) s, scene $((scened - built)) s, viewer $((end - scened)) s)"
case $status in
  0) echo "PASS: the viewer's pictures of orbitforge's final.ply and final.spz match render_orbit (PSNR >= $MIN_PSNR dB)" ;;
  3) skip "Chromium could not start or has no WebGL2" ;;
  *) echo "FAIL: the viewer's picture differs from render_orbit (see above; VIEWER_CHECK_OUT=DIR keeps the pictures)"
     exit 1 ;;
esac
