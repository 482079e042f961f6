#!/usr/bin/env bash
# Fault injection for full_pipeline's resume logic: damaged intermediate files and
# runs killed part-way must either be redone or refused with a message naming the
# file, never end in exit 0 with damaged data kept.
#
#   scripts/check_faults.sh [--quick] [--keep]
#     --quick   4 kill points instead of 20, and one damage per file (the three
#               ways taken in turn over the files; checkpoints keep the 0xFF case)
#     --keep    keep the work folder (printed) instead of removing it
#   BUILD_DIR=build (default; configured when it has no CMakeCache.txt), FAULTS_THREADS=2,
#   FAULTS_KILLS=N overrides the number of kill points.
#
# 1. Builds full_pipeline and ply_tool and runs the tiny synthetic pipeline once
#    (the reference; its final.ply is deterministic for a thread count).
# 2. Damage: every kind of intermediate file (orbit.json, g0/checkpoint.bin,
#    gmed0.ply, R0/0000.png, vhat.json, vhat/0000.png, g1/checkpoint.bin,
#    R1/0000.png, final.ply, each stages/*.json) of a copy of the reference, and
#    g0/partial.bin of a run killed after its first partial checkpoint, is damaged
#    three ways: cut to half, zeroed, random bytes (same size); the checkpoints also
#    a fourth: 256 bytes of 0xFF in the middle (which parse, as NaN parameters).
#    Then the run is repeated. Pass: exit 0, the damaged file rewritten (it no
#    longer holds the damaged bytes) and final.ply byte-identical to the
#    reference's; or an error exit (1 to 127) whose error line names the file. Only
#    the run's own error line(s) count (from its last "full_pipeline: error:" or
#    "stopped:" line on), not the log's progress lines; an exit by a signal (128 and
#    above) fails. A damaged partial.bin must also be reported and not resumed from.
# 3. Kills: K fresh runs are each killed with SIGKILL after T (k + 0.5) / K seconds
#    (T: the reference's wall time), then run again. Pass: the rerun exits 0 with a
#    final.ply byte-identical to the reference's. Temporary files left by a kill
#    are counted.
#
# Everything happens in its own mktemp folder, so several checks may run at once.
set -euo pipefail
cd "$(dirname "$0")/.."
start=$(date +%s.%N)
BUILD_DIR=${BUILD_DIR:-build}
THREADS=${FAULTS_THREADS:-2}
KILLS=${FAULTS_KILLS:-20}
KEEP=0
QUICK=0
for arg in "$@"; do
  case "$arg" in
    --quick) KILLS=${FAULTS_KILLS:-4}; QUICK=1 ;;
    --keep) KEEP=1 ;;
    -h | --help) sed -n '2,30p' "$0"; exit 0 ;;
    *) echo "check_faults.sh: unknown argument '$arg'" >&2; exit 2 ;;
  esac
done

WORK=$(mktemp -d "${TMPDIR:-/tmp}/orbitforge-faults.XXXXXX")
if [ "$KEEP" = 1 ]; then echo "work folder: $WORK"; else trap 'rm -rf "$WORK"' EXIT; fi

echo "== building full_pipeline and ply_tool in $BUILD_DIR"
if [ ! -f "$BUILD_DIR/CMakeCache.txt" ]; then
  launcher=()
  command -v ccache >/dev/null && launcher=(-DCMAKE_CXX_COMPILER_LAUNCHER=ccache)
  generator=()
  command -v ninja >/dev/null && generator=(-G Ninja)
  cmake -S . -B "$BUILD_DIR" "${generator[@]}" "${launcher[@]}" -DCMAKE_BUILD_TYPE=Release >"$WORK/cmake.log" 2>&1 ||
    { cat "$WORK/cmake.log"; exit 1; }
fi
cmake --build "$BUILD_DIR" --parallel "$(nproc)" --target full_pipeline ply_tool >"$WORK/build.log" 2>&1 ||
  { tail -30 "$WORK/build.log"; exit 1; }
FP="$BUILD_DIR/examples/full_pipeline"
PLY_TOOL="$BUILD_DIR/examples/ply_tool"
ARGS=(--width 48 --height 48 --views 73 --iters 300 --median-samples 16 --threads "$THREADS" --checkpoint-every 50)

now() { date +%s.%N; }
# A log line for the summary: without the work folder's path, printable, at most 120 characters.
short() { sed -e "s|$WORK/[^/]*/||g" -e 's/^ *//' | tr -c '[:print:]\n' '?' | cut -c1-120; }
secs() { awk -v a="$1" -v b="$2" 'BEGIN { printf "%.1f", b - a }'; }

# run DIR LOG: the pipeline into DIR; stdout and stderr into LOG; returns its exit status.
run() { "$FP" "${ARGS[@]}" --out "$1" >"$2" 2>&1; }

REF="$WORK/ref"
echo "== reference: full_pipeline ${ARGS[*]}"
t0=$(now)
run "$REF" "$WORK/ref.log" || { tail -20 "$WORK/ref.log"; echo "FAIL: the reference run"; exit 1; }
T=$(secs "$t0" "$(now)")
"$PLY_TOOL" info "$REF/final.ply" >/dev/null || { echo "FAIL: the reference final.ply is not valid"; exit 1; }
echo "reference: ${T} s, final.ply $(stat -c %s "$REF/final.ply") bytes"

fails=0 passes=0 identical=0 checked=0
fail() { echo "FAIL: $*"; fails=$((fails + 1)); }

# damage FILE MODE: cut to half, zeroed or random bytes, in place.
damage() {
  local f=$1 mode=$2 size
  size=$(stat -c %s "$f")
  case "$mode" in
    half) truncate -s $((size / 2)) "$f" ;;
    zero) head -c "$size" /dev/zero >"$f" ;;
    random) head -c "$size" /dev/urandom >"$f" ;;
    ff) head -c 256 /dev/zero | tr '\0' '\377' | dd of="$f" bs=1 seek=$((size / 2)) conv=notrunc status=none ;;
  esac
}

# final_same DIR: final.ply valid and byte-identical to the reference's (a rerun
# redoes the same deterministic work); counts the reruns compared.
final_same() {
  checked=$((checked + 1))
  "$PLY_TOOL" info "$1/final.ply" >/dev/null 2>&1 || return 1
  cmp -s "$1/final.ply" "$REF/final.ply" || return 1
  identical=$((identical + 1))
}

# error_lines LOG: the run's own error message, from its last error or stop line
# to the end (the message may span lines); empty when it printed none.
error_lines() {
  local at
  at=$(grep -an -E "^full_pipeline: (error|stopped):" "$1" | tail -1 | cut -d: -f1)
  [ -n "$at" ] && tail -n "+$at" "$1"
  return 0
}

# judge NAME DIR REL LOG STATUS: the rules of step 2 for the damaged file REL of DIR.
judge() {
  local name=$1 dir=$2 rel=$3 log=$4 status=$5
  if [ "$status" -ge 128 ]; then
    fail "$name: killed by signal $((status - 128)) (exit $status): $(tail -1 "$log" | short)"
    return
  fi
  if [ "$status" -ne 0 ]; then
    local err
    err=$(error_lines "$log")
    if [ -z "$err" ]; then
      fail "$name: exit $status without an error line: $(tail -1 "$log" | short)"
    elif grep -aqF "$rel" <<<"$err"; then
      echo "ok  $name: refused (exit $status): $(grep -aF -m1 "$rel" <<<"$err" | short)"
      passes=$((passes + 1))
    else
      fail "$name: exit $status, its error does not name $rel: $(head -1 <<<"$err" | short)"
    fi
    return
  fi
  if [ -f "$dir/$rel" ] && cmp -s "$dir/$rel" "$dir.damaged"; then
    fail "$name: exit 0 with the damaged $rel kept"
    return
  fi
  if ! final_same "$dir"; then
    fail "$name: exit 0 but final.ply is not the reference's (invalid or different bytes)"
    return
  fi
  local why
  why=$(grep -a -m1 -E "running again|not usable" "$log" | short || true)
  echo "ok  $name: redone, final.ply identical to the reference${why:+ ($why)}"
  passes=$((passes + 1))
}

echo "== damaged files (cut to half, zeroed, random bytes; checkpoints also 0xFF in the middle)"
td=$(now)
files=(orbit.json g0/checkpoint.bin gmed0.ply R0/0000.png vhat.json vhat/0000.png g1/checkpoint.bin R1/0000.png
  final.ply)
for s in "$REF"/stages/*.json; do files+=("stages/$(basename "$s")"); done
n=0
for rel in "${files[@]}"; do
  [ -f "$REF/$rel" ] || { fail "the reference has no $rel"; continue; }
  modes=(half zero random)
  [ "$QUICK" = 1 ] && modes=("${modes[$((n % 3))]}")
  # 0xFF over a stretch of a checkpoint parses (as NaN parameters) unless its checksum is checked.
  case "$rel" in */checkpoint.bin) modes+=(ff) ;; esac
  for mode in "${modes[@]}"; do
    n=$((n + 1))
    dir="$WORK/damage_$n"
    cp -a "$REF" "$dir"
    damage "$dir/$rel" "$mode"
    cp "$dir/$rel" "$dir.damaged"
    status=0
    run "$dir" "$dir.log" || status=$?
    judge "$rel $mode" "$dir" "$rel" "$dir.log" "$status"
    rm -rf "$dir"
  done
done

# partial.bin: a fresh run killed once its first partial checkpoint (and key) exist.
partial_modes=(half zero random ff)
[ "$QUICK" = 1 ] && partial_modes=(half ff)
for mode in "${partial_modes[@]}"; do
  dir="$WORK/partial_$mode"
  "$FP" "${ARGS[@]}" --out "$dir" >"$dir.first.log" 2>&1 &
  pid=$!
  for _ in $(seq 1 600); do
    [ -f "$dir/g0/partial.bin.key" ] && break
    kill -0 "$pid" 2>/dev/null || break
    sleep 0.05
  done
  kill -KILL "$pid" 2>/dev/null || true
  wait "$pid" 2>/dev/null || true
  if [ ! -f "$dir/g0/partial.bin" ]; then
    fail "g0/partial.bin $mode: the first run left no partial checkpoint"
    continue
  fi
  damage "$dir/g0/partial.bin" "$mode"
  cp "$dir/g0/partial.bin" "$dir.damaged"
  status=0
  run "$dir" "$dir.log" || status=$?
  if [ "$status" -eq 0 ] && ! grep -aq "partial.bin not usable" "$dir.log"; then
    fail "g0/partial.bin $mode: the damaged partial checkpoint was not reported"
  elif [ "$status" -eq 0 ] && grep -aq "G0: resuming" "$dir.log"; then
    fail "g0/partial.bin $mode: resumed from the damaged partial checkpoint"
  else
    judge "g0/partial.bin $mode" "$dir" g0/partial.bin "$dir.log" "$status"
  fi
  rm -rf "$dir"
done
echo "damage: $(secs "$td" "$(now)") s"

echo "== SIGKILL at $KILLS points over the reference's ${T} s, then run again"
tk=$(now)
leftovers=0
for k in $(seq 0 $((KILLS - 1))); do
  at=$(awk -v t="$T" -v k="$k" -v n="$KILLS" 'BEGIN { printf "%.2f", t * (k + 0.5) / n }')
  dir="$WORK/kill_$k"
  "$FP" "${ARGS[@]}" --out "$dir" >"$dir.first.log" 2>&1 &
  pid=$!
  sleep "$at"
  killed="killed"
  kill -KILL "$pid" 2>/dev/null || killed="had finished"
  wait "$pid" 2>/dev/null || true
  stage=$(grep -aE "^== stage|^(G0|G1|R0|R1|static|report)" "$dir.first.log" | tail -1 | cut -c1-40 || true)
  status=0
  run "$dir" "$dir.log" || status=$?
  temps=$(find "$dir" -name '*.tmp.*' | wc -l)
  leftovers=$((leftovers + temps))
  if [ "$status" -ne 0 ]; then
    fail "kill at ${at} s ($stage): the rerun exited $status: $(tail -1 "$dir.log" | short)"
  elif ! final_same "$dir"; then
    fail "kill at ${at} s ($stage): after the rerun final.ply is not the reference's (invalid or different bytes)"
  else
    left=""
    [ "$temps" -gt 0 ] && left=", $temps temporary files left"
    echo "ok  kill at ${at} s ($killed; last progress: ${stage:-none}): rerun exit 0, final.ply identical$left"
    passes=$((passes + 1))
  fi
  rm -rf "$dir"
done
echo "kills: $(secs "$tk" "$(now)") s"

echo "== check_faults: $passes passed, $fails failed; final.ply identical to the reference in $identical of $checked" \
  "finished reruns; $leftovers temporary files left by kills; $(secs "$start" "$(now)") s in all"
[ "$fails" -eq 0 ]
