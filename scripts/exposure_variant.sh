#!/usr/bin/env bash
# Writes a copy of a COLMAP folder (images/ + sparse/0) whose photographs differ
# in exposure and white balance, as a camera on automatic settings gives: each
# photograph's channels are scaled by an exposure factor in [0.75, 1.25] times a
# colour-balance factor in [0.88, 1.12] for red and blue (ffmpeg's
# colorchannelmixer on the 8-bit values, clamped; JPEG written again at the
# highest quality), drawn from SEED. Photographs
# whose 1-based number in name order is listed in KEEP stay as they are (the
# withheld ones, scored against what the scene should show).
#
#   scripts/exposure_variant.sh SRC DST [SEED] [KEEP...]
#
# The factors are written to DST/exposure.txt. The model is linked, not copied.
set -euo pipefail
if [ $# -lt 2 ]; then
  echo "usage: $0 SRC DST [SEED] [KEEP...]" >&2
  exit 2
fi
src=$(realpath "$1")
dst=$2
seed=${3:-1}
shift $(( $# < 3 ? $# : 3 ))
keep=" $* "
[ -d "$src/images" ] && [ -d "$src/sparse/0" ] || { echo "$0: $src has no images/ and sparse/0" >&2; exit 2; }
command -v ffmpeg > /dev/null || { echo "$0: ffmpeg is not installed" >&2; exit 2; }
mkdir -p "$dst/images" "$dst/sparse"
ln -sfn "$src/sparse/0" "$dst/sparse/0"
: > "$dst/exposure.txt"
i=0
for img in $(ls "$src/images" | sort); do
  i=$((i + 1))
  if [[ "$keep" == *" $i "* ]]; then
    cp "$src/images/$img" "$dst/images/$img"
    echo "$img 1 1 1 kept" >> "$dst/exposure.txt"
    continue
  fi
  # Three uniform draws from (seed, i): awk's srand/rand are deterministic for a seed.
  read -r r g b < <(awk -v s="$((seed * 1000 + i))" 'BEGIN { srand(s); e = 0.75 + 0.5 * rand();
    printf "%.4f %.4f %.4f\n", e * (0.88 + 0.24 * rand()), e, e * (0.88 + 0.24 * rand()) }')
  ffmpeg -loglevel error -y -i "$src/images/$img" -vf "colorchannelmixer=rr=$r:gg=$g:bb=$b" -q:v 1 "$dst/images/$img"
  echo "$img $r $g $b" >> "$dst/exposure.txt"
done
echo "$0: $i photographs in $dst (factors in $dst/exposure.txt)"
