#!/usr/bin/env bash
# The still check's two figures (how much better the deformation field fits the
# training frames than its MedianGS bake, in dB: whole images / the region where
# it gains most) on recorded videos and seeds: each run is full_pipeline's G0 at
# the paper's budget with the given flags, stopped as soon as the check has
# decided. One row per video, one column per seed, so that the thresholds can be
# set against the spread a static scene gives.
#
#   scripts/still_check_spread.sh OUT_ROOT "VIDEO ..." "SEED ..." [full_pipeline flags ...]
#
# e.g. scripts/still_check_spread.sh out/still "cool_teddy doll" "0 1 2" --still-check 500 --coarse-levels 1
# The data is ../shared/data/v3d (ORBITFORGE_DATA overrides); logs stay in OUT_ROOT.
# CAMERAS=estimated runs the user's path (COLMAP on the source frames, the
# recorded model for scoring only) instead of the recorded cameras.
set -euo pipefail
cd "$(dirname "$0")/.."
out_root=${1:?usage: still_check_spread.sh OUT_ROOT "VIDEO ..." "SEED ..." [flags]}
videos=${2:?usage: still_check_spread.sh OUT_ROOT "VIDEO ..." "SEED ..." [flags]}
seeds=${3:?usage: still_check_spread.sh OUT_ROOT "VIDEO ..." "SEED ..." [flags]}
shift 3
data=${ORBITFORGE_DATA:-../shared/data/v3d}
program=build/examples/full_pipeline
cameras=${CAMERAS:-recorded}
[[ $cameras == recorded || $cameras == estimated ]] ||
  { echo "still_check_spread: CAMERAS must be recorded or estimated, got $cameras" >&2; exit 1; }
[[ -x $program ]] || { echo "still_check_spread: $program not built (cmake --build build)" >&2; exit 1; }
mkdir -p "$out_root"
header="| video |"
rule="|---|"
for s in $seeds; do header+=" seed $s |"; rule+="---|"; done
echo "$header"
echo "$rule"
for v in $videos; do
  [[ -d $data/$v ]] || { echo "still_check_spread: no recorded video $data/$v" >&2; exit 1; }
  row="| $v |"
  for s in $seeds; do
    log=$out_root/$v.seed$s.log
    rm -rf "${out_root:?}/$v.seed$s"
    if [[ $cameras == estimated ]]; then input=(--images "$data/$v/images" --reference "$data/$v"); else input=(--colmap "$data/$v"); fi
    "$program" "${input[@]}" --frames 1-33 --holdout-every 8 --completion oracle --no-comparisons \
      --iters 10000 --iters-g1 10000 --width 896 --height 512 --threads 2 --seed "$s" "$@" \
      --out "$out_root/$v.seed$s" > "$log" 2>&1 &
    pid=$!
    gain=
    while kill -0 "$pid" 2>/dev/null; do
      gain=$(sed -n 's/.*fits the frames \(-\{0,1\}[0-9.]*\) dB better than its bake (\(-\{0,1\}[0-9.]*\) dB.*/\1 \/ \2/p' "$log" | head -1)
      [[ -n $gain ]] && break
      sleep 2
    done
    kill "$pid" 2>/dev/null || true
    wait "$pid" 2>/dev/null || true
    [[ -n $gain ]] || { echo "still_check_spread: $v seed $s ended without a still check, see $log" >&2; exit 1; }
    row+=" $gain |"
  done
  echo "$row"
done
