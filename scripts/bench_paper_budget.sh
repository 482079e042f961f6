#!/usr/bin/env bash
# The whole method at the paper's budget (10,000 iterations for G0 and for G1,
# every frame at 896x512) on recorded videos, oracle completion, every 8th source
# frame withheld, two threads: one table row per video with the wall time of
# each stage and the held-out quality of R0 and R1.
#
#   scripts/bench_paper_budget.sh OUT_ROOT "VIDEO ..." [full_pipeline flags ...]
#
# e.g. scripts/bench_paper_budget.sh out/budget "cool_teddy doll" --still-check 500
# Runs build/examples/full_pipeline; the data is ../shared/data/v3d (ORBITFORGE_DATA
# overrides). Each run's report stays in OUT_ROOT/VIDEO/report.json.
#
# With --protocol paper among the flags the frames keep the protocol's sizes (G0
# at the source frames' own, the canonical views at 896x512). BENCH_RESUME=1
# keeps an existing run directory, so that a run longer than one sitting (the
# paper's protocol takes hours) goes on from its last verified checkpoint; its
# stage times then cover only what ran after the resume. BENCH_PROGRAM names
# another full_pipeline binary: keep a copy for a run that spans code changes,
# since a stage whose settings record changed with the code trains again.
set -euo pipefail
cd "$(dirname "$0")/.."
out_root=${1:?usage: bench_paper_budget.sh OUT_ROOT "VIDEO ..." [flags]}
videos=${2:?usage: bench_paper_budget.sh OUT_ROOT "VIDEO ..." [flags]}
shift 2
data=${ORBITFORGE_DATA:-../shared/data/v3d}
program=${BENCH_PROGRAM:-build/examples/full_pipeline}
[[ -x $program ]] || { echo "bench_paper_budget: $program not built (cmake --build build) or not executable" >&2; exit 1; }
mkdir -p "$out_root"
echo "| video | method wall s | orbit | G0 | static diagnostics | completion | G1 | report | R0 sup held-out dB | R1 sup / gap held-out dB |"
echo "|---|---|---|---|---|---|---|---|---|---|"
size=(--width 896 --height 512)
prev=
for f in "$@"; do
  [[ $prev == --protocol && $f == paper ]] && size=()  # the protocol sets the sizes
  prev=$f
done
for v in $videos; do
  [[ -d $data/$v ]] || { echo "bench_paper_budget: no recorded video $data/$v" >&2; exit 1; }
  [[ ${BENCH_RESUME:-0} == 1 ]] || { rm -rf "${out_root:?}/$v"; : > "$out_root/$v.log"; }
  "$program" --colmap "$data/$v" --frames 1-33 --holdout-every 8 --completion oracle --no-comparisons \
    --iters 10000 --iters-g1 10000 "${size[@]}" --threads 2 --quiet "$@" --out "$out_root/$v" \
    >> "$out_root/$v.log" 2>&1 || { echo "bench_paper_budget: $v failed, see $out_root/$v.log" >&2; exit 1; }
  python3 - "$out_root/$v/report.json" "$v" <<'EOF'
import json, sys
r = json.load(open(sys.argv[1]))
s = r["stages"]
q = r["quality"]
def f(x):
    return "-" if x is None else "%.2f" % x
def stage(k):
    return "%.0f" % s[k] if k in s else "-"
print("| %s | %.0f | %s | %s | %s | %s | %s | %s | %s | %s / %s |" % (
    sys.argv[2], r["total_seconds"], stage("orbit"), stage("g0"), stage("static_proxy"), stage("completion"),
    stage("g1"), stage("report"), f(q["R0"]["supported_heldout"]["psnr"]),
    f(q["R1"]["supported_heldout"]["psnr"]), f(q["R1"]["gap_heldout"]["psnr"])))
EOF
done
