#!/usr/bin/env bash
# Ecosystem check: a PLY written by orbitforge is read by @playcanvas/splat-transform
# (npm), a widely used Gaussian-splat converter.
#
#   scripts/check_splat_transform.sh            # BUILD_DIR=build-splat-transform by default
#
# Steps: build examples/ply_tool; write a random degree-3 scene with the library
# (and, when shared/data is present, re-write the OpenSplat PLY with the library);
# install splat-transform into a temporary prefix; then
#   1. ours.ply -> splat-transform -> theirs.ply: read back with orbitforge, every value
#      must be bit-identical (float32 in, float32 out);
#   2. ours.ply -> splat-transform -> theirs.csv: the CSV values must match what
#      orbitforge read (to the printed precision);
#   3. ours.splat (written by orbitforge) -> splat-transform -> splat.ply: must agree
#      with orbitforge's own reading of ours.splat within the 8-bit quantisation;
#   4. ours.spz (written by orbitforge) -> splat-transform -> spz.theirs.ply: must agree
#      with orbitforge's own reading of ours.spz to float precision, and with ours.ply
#      within the SPZ quantisation steps; ours.ply -> splat-transform -> theirs.spz
#      (version 3), read by orbitforge: within the same steps of ours.ply;
#   5. splat-transform --summary on ours.ply prints its per-column statistics.
# Outside CI (CI unset or "false") it exits 0 with "skipped: ..." when node/npm or
# python3 are missing or the registry is unreachable; with CI=true it installs
# node/npm and python3 with apt-get when missing and fails instead of skipping.
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$(pwd)
BUILD_DIR=${BUILD_DIR:-build-splat-transform}
PACKAGE=${SPLAT_TRANSFORM_PACKAGE:-@playcanvas/splat-transform}

CHECK_NAME=splat-transform
# shellcheck source=scripts/check_lib.sh
source scripts/check_lib.sh  # the working folder is the repository root here

need_node
if ! command -v python3 >/dev/null; then
  if in_ci; then apt_install python3; else skip "python3 (used to compare the outputs) not installed"; fi
fi

WORK=$(mktemp -d "${TMPDIR:-/tmp}/orbitforge-splat-transform.XXXXXX")
trap 'rm -rf "$WORK"' EXIT

echo "== installing $PACKAGE into $WORK/npm"
if ! timeout 600 npm install --no-audit --no-fund --prefix "$WORK/npm" "$PACKAGE" >"$WORK/npm.log" 2>&1; then
  tail -5 "$WORK/npm.log" || true
  skip "npm registry not reachable (npm install $PACKAGE failed)"
fi
ST="$WORK/npm/node_modules/.bin/splat-transform"
[ -x "$ST" ] || { echo "FAIL: $ST missing after npm install"; exit 1; }
echo "installed: $("$ST" --version 2>&1 | head -1)"

echo "== building ply_tool in $BUILD_DIR"
launcher=()
command -v ccache >/dev/null && launcher=(-DCMAKE_CXX_COMPILER_LAUNCHER=ccache)
generator=()
command -v ninja >/dev/null && generator=(-G Ninja)
cmake -S . -B "$BUILD_DIR" "${generator[@]}" "${launcher[@]}" -DCMAKE_BUILD_TYPE=Release \
  -DORBITFORGE_BUILD_EXAMPLES=ON -DORBITFORGE_BUILD_TESTS=OFF >"$WORK/cmake.log" 2>&1 ||
  { cat "$WORK/cmake.log"; exit 1; }
cmake --build "$BUILD_DIR" --target ply_tool >"$WORK/build.log" 2>&1 || { tail -30 "$WORK/build.log"; exit 1; }
TOOL="$BUILD_DIR/examples/ply_tool"

# Runs splat-transform quietly, showing its output only on failure.
st() {
  if ! "$ST" -w "$@" >"$WORK/st.log" 2>&1; then
    cat "$WORK/st.log"
    echo "FAIL: splat-transform $*"
    exit 1
  fi
}

# compare A.ply B.ply TOLERANCE [ROT_TOLERANCE]: same count and degree, every value
# within TOLERANCE (relative to max(1, |value|); rot_* within ROT_TOLERANCE, on unit
# quaternions); 0 means bit-identical float32. The reported difference is scaled to
# TOLERANCE.
compare() {
  "$TOOL" dump "$1" >"$WORK/a.jsonl"
  "$TOOL" dump "$2" >"$WORK/b.jsonl"
  python3 - "$WORK/a.jsonl" "$WORK/b.jsonl" "$3" "$1" "$2" "${4:-$3}" <<'EOF'
import json, math, struct, sys
a = [json.loads(l) for l in open(sys.argv[1])]
b = [json.loads(l) for l in open(sys.argv[2])]
tol = float(sys.argv[3])
rot_tol = float(sys.argv[6]) if len(sys.argv) > 6 else tol
if len(a) != len(b):
    sys.exit(f"FAIL: count {len(a)} in {sys.argv[4]} vs {len(b)} in {sys.argv[5]}")
f32 = lambda x: struct.unpack('<f', struct.pack('<f', x))[0]
if tol:  # approximate comparisons are of decoded .splat data: compare unit quaternions
    for g in a + b:
        n = math.sqrt(sum(g[f'rot_{i}'] ** 2 for i in range(4))) or 1.0
        for i in range(4):
            g[f'rot_{i}'] /= n
worst = {'rot': (0.0, None), 'other': (0.0, None)}
checked = 0
for ga, gb in zip(a, b):
    if set(ga) != set(gb):
        sys.exit(f"FAIL: properties differ at Gaussian {ga['index']}: {sorted(set(ga) ^ set(gb))}")
    for k, va in ga.items():
        if k == 'index':
            continue
        vb = gb[k]
        checked += 1
        if tol == 0:
            if f32(va) != f32(vb) and not (math.isnan(va) and math.isnan(vb)):
                sys.exit(f"FAIL: Gaussian {ga['index']} {k}: {va!r} vs {vb!r} (expected bit-identical)")
            continue
        group = 'rot' if k.startswith('rot_') else 'other'
        err = abs(va - vb) / max(1.0, abs(va))
        if err > worst[group][0]:
            worst[group] = (err, (ga['index'], k, va, vb))
if tol == 0:
    print(f"  ok: {len(a)} Gaussians, {checked} values bit-identical")
    sys.exit(0)
for group, limit in (('other', tol), ('rot', rot_tol)):
    err, at = worst[group]
    where = f" at Gaussian {at[0]} {at[1]}: {at[2]:.7g} vs {at[3]:.7g}" if at else ""
    if err > limit:
        sys.exit(f"FAIL: {group} values differ by {err:.3g} > {limit}{where}")
    print(f"  ok: {len(a)} Gaussians, {group} values: largest difference {err:.3g} (limit {limit}){where}")
EOF
}

echo "== writing scenes with orbitforge"
"$TOOL" random 2000 3 7 "$WORK/ours.ply"
SCENES=("$WORK/ours.ply")
SHARED=${ORBITFORGE_SHARED_DATA:-$ROOT/../shared/data}
if [ -f "$SHARED/ply/opensplat_spheres_10k.ply" ]; then
  "$TOOL" convert "$SHARED/ply/opensplat_spheres_10k.ply" "$WORK/opensplat_ours.ply"
  SCENES+=("$WORK/opensplat_ours.ply")
fi

for scene in "${SCENES[@]}"; do
  name=$(basename "$scene" .ply)
  echo "== $name: orbitforge PLY -> splat-transform -> PLY"
  st "$scene" "$WORK/$name.theirs.ply"
  compare "$scene" "$WORK/$name.theirs.ply" 0

  echo "== $name: orbitforge PLY -> splat-transform -> CSV"
  st "$scene" "$WORK/$name.csv"
  "$TOOL" dump "$scene" >"$WORK/ours.jsonl"
  python3 - "$WORK/$name.csv" "$WORK/ours.jsonl" <<'EOF'
import csv, json, sys
rows = list(csv.DictReader(open(sys.argv[1])))
ours = [json.loads(l) for l in open(sys.argv[2])]
if len(rows) != len(ours):
    sys.exit(f"FAIL: CSV has {len(rows)} rows, orbitforge read {len(ours)}")
checked, worst = 0, 0.0
for r, g in zip(rows, ours):
    for k, v in g.items():
        if k == 'index' or k not in r:
            continue
        d = abs(float(r[k]) - v) / max(1.0, abs(v))
        worst = max(worst, d)
        checked += 1
needed = {'x', 'y', 'z', 'opacity', 'scale_0', 'rot_0', 'f_dc_0'}
missing = needed - set(rows[0].keys()) if rows else set()
if missing:
    sys.exit(f"FAIL: CSV lacks columns {sorted(missing)}")
if worst > 1e-6:
    sys.exit(f"FAIL: CSV values differ by up to {worst:.3g}")
print(f"  ok: {len(rows)} rows, {checked} values match (largest relative difference {worst:.3g})")
EOF
done

echo "== orbitforge .splat -> splat-transform -> PLY"
"$TOOL" convert "$WORK/ours.ply" "$WORK/ours.splat"
"$TOOL" convert "$WORK/ours.splat" "$WORK/ours_from_splat.ply"  # orbitforge's own reading
st "$WORK/ours.splat" "$WORK/splat.theirs.ply"
# Both sides decode the same bytes. Positions, scales, colours and opacity must agree
# to float precision. Rotations: orbitforge decodes a byte as (b - 128) / 128 (the
# antimatter15 viewer's rule) and keeps the quaternion as stored; splat-transform
# 2.x decodes b / 255 * 2 - 1 and normalises, so the unit quaternions differ by up to
# about one byte step (1/128); allow two.
compare "$WORK/ours_from_splat.ply" "$WORK/splat.theirs.ply" 1e-5 0.016

# quantised A.ply B.ply SH1 SHREST: B is A through SPZ: every value within half a
# quantisation step of the format (io/spz.hpp): means 1/4096 (12 fractional bits),
# log scales 1/16, opacity 1/255 (compared as sigmoid), DC colour 1/(0.15*255),
# rotations sqrt(1/2)/511 per stored component (3x for the rebuilt largest one, as
# unit quaternions up to sign); SH within SH1/128 (degree 1) and SHREST/128
# (degrees 2-3), which depend on the writer's bits.
quantised() {
  "$TOOL" dump "$1" >"$WORK/a.jsonl"
  "$TOOL" dump "$2" >"$WORK/b.jsonl"
  python3 - "$WORK/a.jsonl" "$WORK/b.jsonl" "$1" "$2" "$3" "$4" <<'EOF'
import json, math, sys
sh1, sh_rest = float(sys.argv[5]), float(sys.argv[6])
a = [json.loads(l) for l in open(sys.argv[1])]
b = [json.loads(l) for l in open(sys.argv[2])]
if len(a) != len(b):
    sys.exit(f"FAIL: count {len(a)} in {sys.argv[3]} vs {len(b)} in {sys.argv[4]}")
rest = sum(1 for k in a[0] if k.startswith('f_rest_')) // 3 if a else 0
slack = 1e-5
def bound(k):
    if k in ('x', 'y', 'z'): return 0.5 / 4096
    if k.startswith('scale_'): return 0.5 / 16
    if k.startswith('f_dc_'): return 0.5 / (0.15 * 255)
    if k.startswith('f_rest_'): return (sh1 if int(k[7:]) % rest < 3 else sh_rest) / 128
    raise KeyError(k)
sig = lambda v: 1 / (1 + math.exp(-v))
worst = (0.0, None)
for ga, gb in zip(a, b):
    qa = [ga[f'rot_{i}'] for i in range(4)]
    qb = [gb[f'rot_{i}'] for i in range(4)]
    na, nb = math.sqrt(sum(v * v for v in qa)), math.sqrt(sum(v * v for v in qb))
    s = 1.0 if sum(x * y for x, y in zip(qa, qb)) >= 0 else -1.0
    errs = {f'rot_{i}': (abs(qa[i] / na - s * qb[i] / nb), 3 * 0.5 * math.sqrt(0.5) / 511) for i in range(4)}
    errs['opacity'] = (abs(sig(ga['opacity']) - sig(gb['opacity'])), 0.5 / 255)
    for k, v in ga.items():
        if k == 'index' or k.startswith('rot_') or k == 'opacity':
            continue
        errs[k] = (abs(v - gb[k]), bound(k))
    for k, (e, lim) in errs.items():
        r = e / (lim + slack)
        if r > worst[0]:
            worst = (r, (ga['index'], k, ga[k], gb[k], lim))
        if r > 1:
            sys.exit(f"FAIL: Gaussian {ga['index']} {k}: {ga[k]!r} in {sys.argv[3]} vs {gb[k]!r} in {sys.argv[4]}: "
                     f"differs by {e:.3g}, more than the SPZ step allows ({lim:.3g})")
r, at = worst
print(f"  ok: {len(a)} Gaussians within the SPZ quantisation; largest difference {r:.2f} of its bound"
      + (f" (Gaussian {at[0]} {at[1]}: {at[2]:.7g} vs {at[3]:.7g}, bound {at[4]:.3g})" if at else ""))
EOF
}

echo "== orbitforge .spz -> splat-transform -> PLY"
"$TOOL" convert "$WORK/ours.ply" "$WORK/ours.spz"
"$TOOL" convert "$WORK/ours.spz" "$WORK/ours_from_spz.ply"  # orbitforge's own reading
st "$WORK/ours.spz" "$WORK/spz.theirs.ply"
# Both decode the same bytes; splat-transform also turns the format's RUB axes into PLY's.
compare "$WORK/ours_from_spz.ply" "$WORK/spz.theirs.ply" 1e-5 1e-5
# orbitforge keeps 6 and 5 SH bits: steps of 4/128 and 8/128.
quantised "$WORK/ours.ply" "$WORK/spz.theirs.ply" 2 4
echo "== orbitforge PLY -> splat-transform -> .spz (version 3) -> orbitforge"
st "$WORK/ours.ply" --spz-version 3 "$WORK/theirs.spz"
"$TOOL" convert "$WORK/theirs.spz" "$WORK/theirs_spz.ply"
# splat-transform keeps 5 and 4 (steps 8/128 and 16/128) and rounds twice (to a
# byte, then to the step): half a step and half a byte.
quantised "$WORK/ours.ply" "$WORK/theirs_spz.ply" 4.5 8.5

echo "== splat-transform --summary of orbitforge's PLY"
"$ST" "$WORK/ours.ply" --summary null 2>&1 | grep -E '^\*\*Row Count|^\| (Column|x|y|z|opacity|scale_0|rot_0|f_dc_0|f_rest_44) ' || true

echo "PASS: splat-transform reads orbitforge's PLY, .splat and .spz files; orbitforge reads its .spz"
