#!/usr/bin/env bash
# A reference camera model of a recorded orbit video whose loop is closed.
#
#   scripts/closed_loop_reference.sh VIDEO_DIR OUT_DIR [OVERLAP]
#
# VIDEO_DIR holds images/ (the frames in orbit order, e.g. 001.jpg ...). OUT_DIR
# gets images/ (a link to VIDEO_DIR/images), sparse/0/ (a COLMAP text model) and
# colmap/ (database, pair list, logs), so it can stand wherever a recorded
# video's folder does (`--inputs`, `--reference`).
#
# Why: a video that orbits the whole way round ends where it began, but
# COLMAP's sequential matcher never matches its last frames with its first, so
# a model estimated that way does not know the loop closes; its small per-frame
# rotation errors add up along the orbit, and its far side bends away from
# where the frames were shot (docs/cameras.md, "A reference that closes the
# loop"). Here each frame is matched with the next OVERLAP frames around the
# loop (the last with the first), otherwise as a sequential-matcher model:
# one SIMPLE_PINHOLE camera for all frames, CPU SIFT, the mapper with an
# initial triangulation angle of 4 degrees. Only for a video known to close
# its loop: for an arc, matching its ends is wrong.
#
# The model uses every frame, so what it says of frames outside a source run
# is lab evidence: for scoring, never for the method's inputs.
set -euo pipefail

if [[ $# -lt 2 ]]; then
  echo "usage: $0 VIDEO_DIR OUT_DIR [OVERLAP]" >&2
  exit 2
fi
video=$(cd "$1" && pwd)
out=$2
overlap=${3:-8}
[[ -d "$video/images" ]] || { echo "$0: $video/images: no such folder" >&2; exit 2; }
[[ "$overlap" =~ ^[1-9][0-9]*$ ]] || { echo "$0: OVERLAP must be a positive integer, got '$overlap'" >&2; exit 2; }
command -v colmap >/dev/null || { echo "$0: colmap not found (Debian package colmap)" >&2; exit 2; }
export QT_QPA_PLATFORM=offscreen

mapfile -t frames < <(cd "$video/images" && ls | grep -iE '\.(jpg|jpeg|png)$' | LC_ALL=C sort)
n=${#frames[@]}
(( n >= 3 )) || { echo "$0: $video/images has $n frames; 3 are needed" >&2; exit 2; }
(( overlap < n )) || { echo "$0: OVERLAP $overlap must be below the frame count $n" >&2; exit 2; }

# A fresh model in a temporary folder, moved into place at the end: a failed
# run leaves OUT_DIR as it was.
mkdir -p "$out"
out=$(cd "$out" && pwd)
work=$(mktemp -d "$out/.closed_loop.XXXXXX")
trap 'rm -rf "$work"' EXIT
mkdir -p "$work/colmap/logs" "$work/sparse/0" "$work/colmap/model"
db="$work/colmap/database.db"
threads=${ORBITFORGE_COLMAP_THREADS:-2}

colmap feature_extractor --database_path "$db" --image_path "$video/images" \
  --ImageReader.single_camera 1 --ImageReader.camera_model SIMPLE_PINHOLE \
  --SiftExtraction.use_gpu 0 --SiftExtraction.num_threads "$threads" \
  > "$work/colmap/logs/feature_extractor.log" 2>&1

pairs="$work/colmap/pairs.txt"
: > "$pairs"
for (( i = 0; i < n; ++i )); do
  for (( d = 1; d <= overlap; ++d )); do
    echo "${frames[i]} ${frames[(i + d) % n]}" >> "$pairs"
  done
done
colmap matches_importer --database_path "$db" --match_list_path "$pairs" --match_type pairs \
  --SiftMatching.use_gpu 0 --SiftMatching.num_threads "$threads" \
  > "$work/colmap/logs/matches_importer.log" 2>&1

colmap mapper --database_path "$db" --image_path "$video/images" --output_path "$work/colmap/model" \
  --Mapper.init_min_tri_angle 4 --Mapper.num_threads "$threads" \
  > "$work/colmap/logs/mapper.log" 2>&1

# The largest model (COLMAP numbers them 0, 1, ...), as text.
best="" best_images=0
for m in "$work"/colmap/model/*/; do
  [[ -f "$m/images.bin" ]] || continue
  count=$(colmap model_analyzer --path "$m" 2>&1 | sed -n 's/.*Registered images: *\([0-9]*\).*/\1/p' | head -1)
  if (( ${count:-0} > best_images )); then best=$m best_images=${count:-0}; fi
done
[[ -n "$best" ]] || { echo "$0: COLMAP made no model (logs: $work/colmap/logs kept in $out/colmap.failed)" >&2
                      rm -rf "$out/colmap.failed"; cp -r "$work/colmap" "$out/colmap.failed"; exit 1; }
colmap model_converter --input_path "$best" --output_path "$work/sparse/0" --output_type TXT \
  > "$work/colmap/logs/model_converter.log" 2>&1

rm -rf "$out/sparse" "$out/colmap"
mv "$work/sparse" "$out/sparse"
mv "$work/colmap" "$out/colmap"
ln -sfn "$video/images" "$out/images"
echo "$out: $best_images of $n frames registered (pairs: each frame with the next $overlap around the loop)"
