#!/usr/bin/env bash
# A local web viewer for a PLY orbitforge wrote (Spark, a three.js Gaussian-splat
# renderer from npm, with orbit controls):
#
#   scripts/view.sh out/pipeline/final.ply [--port 8080] [--camera orbit.json] [--bg r,g,b]
#
# Installs the viewer's pinned npm packages (scripts/viewer/package-lock.json) into
# ${XDG_CACHE_HOME:-~/.cache}/orbitforge-viewer the first time, then serves the page and
# the PLY's folder on 127.0.0.1 and prints the URL to open. The view starts at the first
# camera of --camera (default: orbit.json beside the PLY, when there is one) and orbits
# about the orbit's look-at point with the orbit's normal up. Ctrl-C stops it.
set -euo pipefail
ROOT=$(cd "$(dirname "$0")/.." && pwd)
usage() {
  echo "usage: scripts/view.sh SCENE.ply [--port N] [--camera CAMERAS.json] [--bg r,g,b]" >&2
  exit 2
}
[ $# -ge 1 ] || usage
case "$1" in -h | --help) usage ;; esac
PLY=$1
shift
PORT=8080
CAMERA=""
BG=""
while [ $# -gt 0 ]; do
  case "$1" in
    --port) [ $# -ge 2 ] || usage; PORT=$2; shift 2 ;;
    --camera) [ $# -ge 2 ] || usage; CAMERA=$2; shift 2 ;;
    --bg) [ $# -ge 2 ] || usage; BG=$2; shift 2 ;;
    *) echo "view.sh: unknown argument '$1'" >&2; usage ;;
  esac
done
[[ "$PORT" =~ ^[0-9]+$ ]] && [ "$PORT" -le 65535 ] || { echo "view.sh: --port must be 0..65535, got '$PORT'" >&2; exit 2; }
[ -f "$PLY" ] || { echo "view.sh: $PLY: no such file" >&2; exit 1; }
head -c 3 "$PLY" | grep -q '^ply' || { echo "view.sh: $PLY is not a PLY file (no 'ply' magic)" >&2; exit 1; }
DATA=$(cd "$(dirname "$PLY")" && pwd)
NAME=$(basename "$PLY")
if [ -z "$CAMERA" ] && [ -f "$DATA/orbit.json" ]; then CAMERA="$DATA/orbit.json"; fi
CAMERA_NAME=""
if [ -n "$CAMERA" ]; then
  [ -f "$CAMERA" ] || { echo "view.sh: --camera $CAMERA: no such file" >&2; exit 1; }
  # Only the PLY's folder is served.
  [ "$(cd "$(dirname "$CAMERA")" && pwd)" = "$DATA" ] ||
    { echo "view.sh: --camera $CAMERA must be in the PLY's folder $DATA" >&2; exit 1; }
  CAMERA_NAME=$(basename "$CAMERA")
fi

command -v node >/dev/null && command -v npm >/dev/null ||
  { echo "view.sh: node and npm are needed (Debian: apt-get install nodejs npm)" >&2; exit 1; }

# The cache folder is keyed by the lock file, so a version change installs afresh.
LOCK="$ROOT/scripts/viewer/package-lock.json"
KEY=$(sha256sum "$LOCK" | cut -c1-16)
CACHE="${XDG_CACHE_HOME:-$HOME/.cache}/orbitforge-viewer/$KEY"
if [ ! -f "$CACHE/.installed" ]; then
  echo "view.sh: installing the viewer into $CACHE (once)"
  mkdir -p "$CACHE"
  cp "$ROOT/scripts/viewer/package.json" "$LOCK" "$CACHE/"
  if ! (cd "$CACHE" && PLAYWRIGHT_SKIP_BROWSER_DOWNLOAD=1 npm ci --omit=optional --no-audit --no-fund >"$CACHE/npm.log" 2>&1); then
    tail -5 "$CACHE/npm.log" >&2
    echo "view.sh: npm ci failed (is the npm registry reachable?); log in $CACHE/npm.log" >&2
    exit 1
  fi
  touch "$CACHE/.installed"
fi

args=(--modules "$CACHE/node_modules" --data "$DATA" --ply "$NAME" --port "$PORT")
[ -n "$CAMERA_NAME" ] && args+=(--camera "$CAMERA_NAME")
[ -n "$BG" ] && args+=(--bg "$BG")
exec node "$ROOT/scripts/viewer/server.mjs" "${args[@]}"
