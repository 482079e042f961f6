#!/usr/bin/env bash
# A recorded video with motion added: every frame's content is shifted by
# (-A sin(2 pi n / P), -A cos(2 pi n / P)) pixels, n the frame number from 0,
# the uncovered border filled white (the recorded videos' background); the
# cameras (sparse/0) are kept. The scene then moves along a small circle that
# no static model can explain, which gives the still check a known positive.
# With PART=part only the box x in [W/4, 3W/4), y in [H/4, H/2) moves (an eighth
# of the frame, the upper middle where the object's top is), the rest stays: a
# part of the object moving, which a whole-image mean dilutes. With PART=small
# only x in [3W/8, 5W/8), y in [H/4, 3H/8) moves: a thirty-second of the frame.
#
#   scripts/make_moving_video.sh SRC_DIR DST_DIR AMPLITUDE_PX PERIOD_FRAMES [part|small]
#
# e.g. scripts/make_moving_video.sh ../shared/data/v3d/doll out/moving/doll 4 16
set -euo pipefail
src=${1:?usage: make_moving_video.sh SRC_DIR DST_DIR AMPLITUDE_PX PERIOD_FRAMES}
dst=${2:?usage: make_moving_video.sh SRC_DIR DST_DIR AMPLITUDE_PX PERIOD_FRAMES}
amp=${3:?usage: make_moving_video.sh SRC_DIR DST_DIR AMPLITUDE_PX PERIOD_FRAMES}
period=${4:?usage: make_moving_video.sh SRC_DIR DST_DIR AMPLITUDE_PX PERIOD_FRAMES}
part=${5:-}
[[ -z $part || $part == part || $part == small ]] ||
  { echo "make_moving_video: the fifth argument is 'part', 'small' or nothing, got $part" >&2; exit 1; }
[[ -d $src/images && -d $src/sparse/0 ]] || { echo "make_moving_video: $src has no images/ and sparse/0" >&2; exit 1; }
[[ $amp =~ ^[0-9]+$ && $amp -ge 1 ]] || { echo "make_moving_video: amplitude must be a whole number of pixels >= 1, got $amp" >&2; exit 1; }
[[ $period =~ ^[0-9]+$ && $period -ge 2 ]] || { echo "make_moving_video: period must be a whole number of frames >= 2, got $period" >&2; exit 1; }
command -v ffmpeg > /dev/null || { echo "make_moving_video: ffmpeg not found (apt-get install ffmpeg)" >&2; exit 1; }
first=$(ls "$src/images" | sort | head -1)
[[ $first =~ ^([0-9]+)\.jpg$ ]] || { echo "make_moving_video: expected images/NNN.jpg, found $first" >&2; exit 1; }
digits=${#BASH_REMATCH[1]}
start=$((10#${BASH_REMATCH[1]}))
rm -rf "$dst"
mkdir -p "$dst/images" "$dst/sparse"
cp -r "$src/sparse/0" "$dst/sparse/0"
a=$amp
shift_frame="pad=iw+2*$a:ih+2*$a:$a:$a:white,crop=iw-2*$a:ih-2*$a:$a+$a*sin(2*PI*n/$period):$a+$a*cos(2*PI*n/$period)"
case $part in  # the moving box: its crop (w:h:x:y) and where it goes back
  part) box=iw/2:ih/4:iw/4:ih/4 at=W/4:H/4 ;;
  small) box=iw/4:ih/8:iw*3/8:ih/4 at=W*3/8:H/4 ;;
esac
if [[ -n $part ]]; then
  filter="format=rgb24,split[base][moved];[moved]$shift_frame,crop=$box[box];[base][box]overlay=$at:format=rgb"
else
  filter=$shift_frame
fi
ffmpeg -loglevel error -start_number "$start" -i "$src/images/%0${digits}d.jpg" \
  -filter_complex "$filter" -q:v 2 -start_number "$start" "$dst/images/%0${digits}d.jpg"
[[ $(ls "$dst/images" | wc -l) == $(ls "$src/images" | wc -l) ]] ||
  { echo "make_moving_video: wrote $(ls "$dst/images" | wc -l) frames of $(ls "$src/images" | wc -l)" >&2; exit 1; }
echo "make_moving_video: $dst (shift up to $amp px, period $period frames${part:+, the upper middle $part box only})"
