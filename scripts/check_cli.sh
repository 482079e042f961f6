#!/usr/bin/env bash
# The example programs' command lines: every program answers --help with status 0
# and a usage line; sizes a user types are refused before anything is allocated;
# an unknown flag and a flag without its value are refused (status 2) by name;
# fit_orbit's --frames counts video frames, registered or not, as the pipeline does;
# audit names a malformed scheduler variable (its shard) and exits 2; the settings
# full_pipeline and reconstruct write replay the run with --config.
#
#   scripts/check_cli.sh BUILD/examples
set -euo pipefail
bin=${1:?usage: check_cli.sh BUILD/examples}
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
fail() { echo "check_cli: $*" >&2; exit 1; }

for p in audit fit_orbit full_pipeline host_adaptor make_prompt orbit_from_gl ply_tool reconstruct render_orbit; do
  [[ -x "$bin/$p" ]] || fail "$bin/$p is not built"
  rc=0
  "$bin/$p" --help > "$work/help.txt" 2> "$work/help.err" || rc=$?
  [[ $rc == 0 ]] || fail "$p --help exits $rc: $(head -c 300 "$work/help.err")"
  grep -qi "usage" "$work/help.txt" || fail "$p --help prints no usage on stdout"
done

# A status and the stderr line that must name the problem.
expect_refusal() {  # STATUS PATTERN COMMAND...
  local want=$1 pattern=$2 rc=0
  shift 2
  "$@" > "$work/out.txt" 2> "$work/err.txt" || rc=$?
  [[ $rc == "$want" ]] || fail "$* exits $rc, expected $want: $(head -c 300 "$work/err.txt")"
  grep -q -- "$pattern" "$work/err.txt" || fail "$*: stderr does not say '$pattern': $(head -c 300 "$work/err.txt")"
}
start=$(date +%s%N)
expect_refusal 2 "--views" "$bin/fit_orbit" --synthetic --views 100000000 --out "$work/o.json"
ms=$(( ($(date +%s%N) - start) / 1000000 ))
(( ms < 1000 )) || fail "--views 100000000 took $ms ms to refuse"
expect_refusal 2 "--views" "$bin/full_pipeline" --views 100000000 --out "$work/run"
expect_refusal 2 "--init-points" "$bin/full_pipeline" --init-points 20000000 --out "$work/run"
expect_refusal 2 "--image-order" "$bin/full_pipeline" --image-order spiral --out "$work/run"
expect_refusal 2 "--image-order ring goes with --colmap" "$bin/full_pipeline" --images "$work" --image-order ring \
  --out "$work/run"
expect_refusal 2 "--frames" "$bin/fit_orbit" --synthetic --frames '' --out "$work/o.json"
[[ ! -e "$work/o.json" ]] || fail "a refused fit_orbit left orbit.json"
# An unknown flag and a flag missing its value: status 2, the flag named.
expect_refusal 2 "--no-such-flag" "$bin/full_pipeline" --no-such-flag --out "$work/run"
expect_refusal 2 "--no-such-flag" "$bin/fit_orbit" --synthetic --no-such-flag --out "$work/o.json"
expect_refusal 2 "--iters" "$bin/reconstruct" --colmap "$work/none" --out "$work/rec" --iters
expect_refusal 2 "--learn-background and --background random" "$bin/reconstruct" --colmap "$work/none" \
  --out "$work/rec" --learn-background --background random
expect_refusal 2 "--views" "$bin/fit_orbit" --synthetic --out "$work/o.json" --views
expect_refusal 2 "--config" "$bin/audit" --inputs "$work/none" --completion oracle --out "$work/audit" --config
[[ ! -e "$work/o.json" && ! -e "$work/rec" && ! -e "$work/run" ]] || fail "a refused command left outputs"
# The audit's shard from a scheduler: a bad variable is named, status 2, before any work.
expect_refusal 2 "SLURM_ARRAY_TASK_ID" env SLURM_ARRAY_TASK_ID=x SLURM_ARRAY_TASK_MIN=0 SLURM_ARRAY_TASK_COUNT=2 \
  "$bin/audit" --inputs "$work/none" --completion oracle --out "$work/audit"
expect_refusal 2 "--shard-count" env -u SLURM_ARRAY_TASK_ID JOB_COMPLETION_INDEX=0 \
  "$bin/audit" --inputs "$work/none" --completion oracle --out "$work/audit"

# A 91-frame video whose model registered every frame but 29-33: frames 1-33 are
# the 28 registered ones, and the 5 others are named.
"$bin/fit_orbit" --synthetic --views 91 --out "$work/o.json" --export-colmap "$work/video/sparse/0" > /dev/null
mkdir -p "$work/video/images"
for i in $(seq 0 90); do : > "$work/video/images/$(printf %05d.png "$i")"; done
python3 - "$work/video/sparse/0/images.txt" <<'PY'
import sys
path = sys.argv[1]
lines = open(path).read().split("\n")
out, i = [], 0
while i < len(lines):
    l = lines[i]
    if l.startswith("#") or not l.strip():
        out.append(l); i += 1; continue
    name = l.split()[-1]
    if name not in {"%05d.png" % k for k in range(28, 33)}:
        out += [l, lines[i + 1] if i + 1 < len(lines) else ""]
    i += 2
open(path, "w").write("\n".join(out))
PY
"$bin/fit_orbit" --colmap "$work/video" --frames 1-33 --out "$work/o.json" > "$work/fit.txt"
grep -q "skipping 5 frames without a camera: frame 29 (00028.png)" "$work/fit.txt" || fail "unregistered frames not named: $(cat "$work/fit.txt")"
grep -q "fit_orbit: 28 cameras used" "$work/fit.txt" || fail "expected 28 cameras: $(cat "$work/fit.txt")"
grep -q "arc 0 to [0-9.]* deg" "$work/fit.txt" || fail "arc not in degrees: $(cat "$work/fit.txt")"
expect_refusal 1 "none of its 5 frames has a camera" "$bin/fit_orbit" --colmap "$work/video" --frames 29-33 --out "$work/o2.json"
expect_refusal 1 "beyond the 91 frames" "$bin/fit_orbit" --colmap "$work/video" --frames 1-95 --out "$work/o2.json"
# --config replays a run: the settings a run wrote (OUT/settings.toml), read back
# with only --out given, make the same run; report.json / metrics.json record the
# command line and those settings.
tiny=(--width 32 --height 32 --iters 4 --median-samples 2 --seed 5 --threads 2)
"$bin/full_pipeline" "${tiny[@]}" --views 9 --init-points 300 --completion none --quiet --prompt "a 'quoted' prompt" \
  --out "$work/p1" > /dev/null 2> "$work/p1.err" || fail "tiny full_pipeline failed: $(tail -c 600 "$work/p1.err")"
[[ -s "$work/p1/settings.toml" ]] || fail "full_pipeline wrote no settings.toml"
"$bin/full_pipeline" --config "$work/p1/settings.toml" --out "$work/p2" > /dev/null 2> "$work/p2.err" ||
  fail "full_pipeline --config failed: $(tail -c 600 "$work/p2.err")"
# The same settings spelled otherwise resume the run: the command is a record, in no
# stage key, so every stage is skipped and report.json keeps the command that wrote it.
cp "$work/p1/report.json" "$work/p1.report.json"
"$bin/full_pipeline" --config "$work/p1/settings.toml" > /dev/null 2> "$work/p1b.err" ||
  fail "full_pipeline --config resuming its own folder failed: $(tail -c 600 "$work/p1b.err")"
cmp -s "$work/p1/report.json" "$work/p1.report.json" || fail "a resumed run spelled otherwise rewrote report.json"
"$bin/audit" --write-synthetic "$work/scene" --width 32 --height 32 2> /dev/null || fail "audit --write-synthetic failed"
"$bin/reconstruct" --colmap "$work/scene" "${tiny[@]}" --frames 1-12 --holdout-every 4 --deformable --field 2x8 \
  --out "$work/r1" 2> "$work/r1.err" || fail "tiny reconstruct failed: $(tail -c 600 "$work/r1.err")"
"$bin/reconstruct" --config "$work/r1/settings.toml" --out "$work/r2" 2> "$work/r2.err" ||
  fail "reconstruct --config failed: $(tail -c 600 "$work/r2.err")"
python3 - "$work" <<'PY' || fail "--config did not replay the run"
import json, sys
w = sys.argv[1]
def load(run, name): return json.load(open(f"{w}/{run}/{name}"))
def settings(run): return [l for l in open(f"{w}/{run}/settings.toml") if not l.startswith("out=")]
a, b = load("p1", "report.json"), load("p2", "report.json")
s = a["settings"]
assert (s["iters_g0"], s["iters_g1"], s["views"], s["width"], s["median_samples"]) == (4, 4, 9, 32, 2), s
assert "init-points=300" in open(f"{w}/p2/settings.toml").read().split("\n"), "the replay lost --init-points"
for key in ("settings", "prompt", "background", "frames", "completion_provider"):
    assert a[key] == b[key], (key, a[key], b[key])
assert "--prompt 'a '\\''quoted'\\'' prompt'" in a["invocation"]["command"], a["invocation"]["command"]
assert b["invocation"]["command"].endswith(f"--config {w}/p1/settings.toml --out {w}/p2"), b["invocation"]
assert a["invocation"]["settings"] == open(f"{w}/p1/settings.toml").read()
assert settings("p1") == settings("p2"), "full_pipeline: the replayed run resolved other settings"
m, n = load("r1", "metrics.json"), load("r2", "metrics.json")
assert m["iterations"] == 4 and m["field"] == "2x8" and "holdout_psnr" in m, m
for key in ("iterations", "field", "points", "background", "frame"):
    assert m[key] == n[key], (key, m[key], n[key])
assert "--field 2x8" in m["invocation"]["command"] and "--config" in n["invocation"]["command"]
assert settings("r1") == settings("r2"), "reconstruct: the replayed run resolved other settings"
PY

echo "check_cli: ok (--help everywhere, --views refused in $ms ms, unknown flags and missing values named, fit_orbit frames by video number, --config replays full_pipeline and reconstruct)"
