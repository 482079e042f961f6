#!/usr/bin/env bash
# Converts a Gaussian scene (.ply or .spz, e.g. a run's final.ply / final.spz) to
# PlayCanvas SOG (.sog) with @playcanvas/splat-transform from the npm registry.
#
#   scripts/export_sog.sh IN.ply|IN.spz OUT.sog
#
# splat-transform is installed once into SPLAT_TRANSFORM_PREFIX (default
# ~/.cache/orbitforge/splat-transform; SPLAT_TRANSFORM_PACKAGE picks the version).
# SOG compression runs on a GPU (WebGPU) when there is one; without one it falls
# back to splat-transform's CPU path (-g cpu), which is slower (~40 s for a small
# scene on 2 cores). SOG_DEVICE=cpu or an adapter index skips the first try.
set -euo pipefail
if [ $# -eq 1 ] && { [ "$1" = --help ] || [ "$1" = -h ]; }; then
  sed -n '2,11p' "$0" | sed 's/^# \{0,1\}//'
  exit 0
fi
[ $# -eq 2 ] || { echo "usage: scripts/export_sog.sh IN.ply|IN.spz OUT.sog" >&2; exit 2; }
in=$1
out=$2
case "$in" in *.ply | *.spz) ;; *) echo "export_sog: $in: expected a .ply or .spz file" >&2; exit 2 ;; esac
case "$out" in *.sog) ;; *) echo "export_sog: $out: the output must end in .sog" >&2; exit 2 ;; esac
[ -f "$in" ] || { echo "export_sog: $in: file does not exist" >&2; exit 1; }
command -v npm >/dev/null || { echo "export_sog: npm not installed (Debian: apt-get install nodejs npm)" >&2; exit 1; }

PREFIX=${SPLAT_TRANSFORM_PREFIX:-$HOME/.cache/orbitforge/splat-transform}
PACKAGE=${SPLAT_TRANSFORM_PACKAGE:-@playcanvas/splat-transform}
ST="$PREFIX/node_modules/.bin/splat-transform"
if [ ! -x "$ST" ]; then
  echo "== installing $PACKAGE into $PREFIX"
  mkdir -p "$PREFIX"
  timeout 600 npm install --no-audit --no-fund --prefix "$PREFIX" "$PACKAGE" >"$PREFIX/npm.log" 2>&1 ||
    { tail -5 "$PREFIX/npm.log"; echo "export_sog: npm install $PACKAGE failed" >&2; exit 1; }
fi

log=$(mktemp)
trap 'rm -f "$log"' EXIT
if [ -n "${SOG_DEVICE:-}" ]; then
  "$ST" -w -g "$SOG_DEVICE" "$in" "$out" >"$log" 2>&1 || { cat "$log"; exit 1; }
elif ! "$ST" -w "$in" "$out" >"$log" 2>&1; then
  echo "== no usable GPU for SOG compression; using splat-transform's CPU path (-g cpu)"
  "$ST" -w -g cpu "$in" "$out" >"$log" 2>&1 || { cat "$log"; exit 1; }
fi
echo "export_sog: $in ($(stat -c %s "$in") bytes) -> $out ($(stat -c %s "$out") bytes)"
