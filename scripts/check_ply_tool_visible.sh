#!/usr/bin/env bash
# ply_tool visible on a random scene: a camera facing it keeps (nearly) every
# Gaussian, one facing away keeps none, and a camera range selects cameras.
#
#   scripts/check_ply_tool_visible.sh PATH/TO/ply_tool
set -euo pipefail
tool=${1:?usage: check_ply_tool_visible.sh PATH/TO/ply_tool}
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
"$tool" random 2000 0 1 "$work/scene.ply"
# Means in [-2, 2]^3; the camera looks down +z from 8 units away (half-width 5.1
# at the far side of the box), the second one has the scene behind it.
cat > "$work/cameras.json" <<'JSON'
{"cameras": [
 {"R": [[1,0,0],[0,1,0],[0,0,1]], "t": [0,0,8], "fx": 100, "fy": 100, "cx": 64, "cy": 64, "width": 128, "height": 128},
 {"R": [[1,0,0],[0,1,0],[0,0,1]], "t": [0,0,-8], "fx": 100, "fy": 100, "cx": 64, "cy": 64, "width": 128, "height": 128}
]}
JSON
"$tool" visible "$work/scene.ply" "$work/cameras.json" > "$work/both.json"
"$tool" visible "$work/scene.ply" "$work/cameras.json" 1 1 > "$work/away.json"
python3 - "$work/both.json" "$work/away.json" <<'PY'
import json, sys
both, away = (json.load(open(p)) for p in sys.argv[1:3])
assert both["gaussians"] == 2000 and both["cameras"] == 2, both
assert both["kept_per_camera"]["min"] == 0, both             # the camera facing away
assert 0.49 <= both["kept_per_camera"]["mean"] <= 0.5, both  # the other keeps (nearly) all
assert both["kept_by_no_camera"] <= 20, both
assert away["cameras"] == 1 and away["kept_by_no_camera"] == 2000, away
print("ply_tool visible: ok", both["kept_per_camera"], both["kept_by_no_camera"])
PY
if "$tool" visible "$work/scene.ply" "$work/cameras.json" 1 0 2> "$work/err"; then
  echo "ply_tool visible: a reversed camera range was accepted" >&2; exit 1
fi
grep -q "cameras 1..0 of 2" "$work/err" || { cat "$work/err" >&2; exit 1; }
if "$tool" visible "$work/scene.ply" "$work/cameras.json" 0 5 2> "$work/err"; then
  echo "ply_tool visible: a range past the last camera was accepted" >&2; exit 1
fi
grep -q "cameras 0..5 of 2" "$work/err" || { cat "$work/err" >&2; exit 1; }
