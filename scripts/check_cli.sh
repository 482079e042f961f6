#!/usr/bin/env bash
# The example programs' command lines: every program answers --help with status 0
# and a usage line; sizes a user types are refused before anything is allocated;
# fit_orbit's --frames counts video frames, registered or not, as the pipeline does;
# audit names a malformed scheduler variable (its shard) and exits 2.
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
expect_refusal 2 "--frames" "$bin/fit_orbit" --synthetic --frames '' --out "$work/o.json"
[[ ! -e "$work/o.json" ]] || fail "a refused fit_orbit left orbit.json"
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
echo "check_cli: ok (--help everywhere, --views refused in $ms ms, fit_orbit frames by video number)"
