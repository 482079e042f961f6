#!/usr/bin/env bash
# The audit under a real scheduler: a one-node Slurm cluster on localhost runs
# scripts/slurm/audit.sbatch as a two-task array over two tiny synthetic inputs,
# then `audit --report-only` merges them and the merged table must have both rows.
#
#   scripts/check_slurm.sh [AUDIT]          # AUDIT: default build/examples/audit
#
# Steps: install slurm-wlm and munge with apt-get when missing; write a munge key
# and a slurm.conf (one node, localhost, free ports) into a temporary folder;
# start munged, slurmctld and slurmd there (pid files, logs, state and spool all
# in that folder, so runs never share anything and a second run starts clean);
# wait for the node to be idle; write two inputs with `audit --write-synthetic`;
# sbatch --wait the array; merge; check. Every daemon it started is stopped on
# exit, whatever happened. Needs root (the daemons run as SlurmUser=root).
# Outside CI (CI unset or "false") it exits 0 with "skipped: ..." when the
# packages cannot be installed; with CI=true it fails instead.
set -euo pipefail
cd "$(dirname "$0")/.."
AUDIT=$(realpath -m "${1:-build/examples/audit}")
start=$(date +%s)

CHECK_NAME=Slurm
# shellcheck source=scripts/check_lib.sh
source scripts/check_lib.sh  # the working folder is the repository root here
fail() {
  echo "FAIL: $*"
  exit 1
}

[ -x "$AUDIT" ] || fail "$AUDIT is not built (cmake --build build --target audit)"
[ "$(id -u)" -eq 0 ] || skip "needs root: slurmd and slurmctld run as SlurmUser=root here"
missing=()
for pair in slurmctld:slurm-wlm slurmd:slurm-wlm sbatch:slurm-wlm munged:munge; do
  command -v "${pair%%:*}" >/dev/null || missing+=("${pair##*:}")
done
if [ ${#missing[@]} -gt 0 ]; then
  packages=$(printf '%s\n' "${missing[@]}" | sort -u | tr '\n' ' ')
  echo "== installing $packages with apt-get"
  # shellcheck disable=SC2086
  if ! { apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends $packages; } \
    >/tmp/orbitforge-slurm-apt.log 2>&1; then
    tail -5 /tmp/orbitforge-slurm-apt.log || true
    skip "could not install $packages with apt-get"
  fi
fi
command -v python3 >/dev/null || skip "python3 (picks free ports, reads the table) not installed"

# munged checks that everyone may traverse its socket's folder: 0755, not mktemp's 0700.
WORK=$(mktemp -d "${TMPDIR:-/tmp}/orbitforge-slurm.XXXXXX")
chmod 755 "$WORK"
export SLURM_CONF="$WORK/slurm.conf"

stop_daemons() {
  local status=$?
  set +e
  # Jobs first (their slurmstepd outlives slurmd), then the daemons, newest first.
  if [ -s "$WORK/slurmctld.pid" ]; then
    scancel --quiet --full --user=root 2>/dev/null  # this private cluster's jobs only (SLURM_CONF)
    for _ in $(seq 40); do [ -z "$(squeue --noheader 2>/dev/null)" ] && break; sleep 0.25; done
  fi
  local pidfile pid
  for pidfile in "$WORK/slurmd.pid" "$WORK/slurmctld.pid" "$WORK/munge/munged.pid"; do
    [ -s "$pidfile" ] || continue
    pid=$(cat "$pidfile")
    kill "$pid" 2>/dev/null || continue
    for _ in $(seq 50); do kill -0 "$pid" 2>/dev/null || break; sleep 0.1; done
    kill -0 "$pid" 2>/dev/null && { echo "note: $pidfile ($pid) ignored SIGTERM, killing"; kill -9 "$pid"; }
  done
  if [ "$status" -ne 0 ]; then
    echo "== logs ($WORK/log)"
    for f in "$WORK"/log/*; do [ -f "$f" ] && { echo "-- $f"; tail -n 15 "$f"; }; done
  fi
  rm -rf "$WORK"
  exit "$status"
}
trap stop_daemons EXIT
trap 'exit 130' INT TERM

mkdir -p "$WORK"/{munge,state,spool,log,inputs,out}
chmod 755 "$WORK/munge"
head -c 1024 /dev/urandom >"$WORK/munge/munge.key"
chmod 400 "$WORK/munge/munge.key"
munged --key-file="$WORK/munge/munge.key" --socket="$WORK/munge/munge.sock" \
  --pid-file="$WORK/munge/munged.pid" --log-file="$WORK/log/munged.log" --seed-file="$WORK/munge/munged.seed" ||
  fail "munged did not start"

# Ports the kernel says are free now, so a cluster on the default ports (or a
# second check running beside this one) is left alone.
read -r ctld_port slurmd_port < <(python3 -c '
import socket
socks = [socket.socket() for _ in range(2)]
for s in socks: s.bind(("127.0.0.1", 0))
print(*[s.getsockname()[1] for s in socks])')

cat >"$SLURM_CONF" <<EOF
# One node on localhost for scripts/check_slurm.sh (written by it, removed after).
ClusterName=orbitforgecheck
SlurmctldHost=localhost(127.0.0.1)
SlurmctldPort=$ctld_port
SlurmdPort=$slurmd_port
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
CredType=cred/munge
AuthInfo=socket=$WORK/munge/munge.sock
StateSaveLocation=$WORK/state
SlurmdSpoolDir=$WORK/spool
SlurmctldPidFile=$WORK/slurmctld.pid
SlurmdPidFile=$WORK/slurmd.pid
SlurmctldLogFile=$WORK/log/slurmctld.log
SlurmdLogFile=$WORK/log/slurmd.log
# No cgroups in containers: track processes by parent pid, bind nothing.
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SelectType=select/cons_tres
SelectTypeParameters=CR_CPU
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
MpiDefault=none
ReturnToService=2
MailProg=/bin/true
KillWait=5
NodeName=localhost NodeAddr=127.0.0.1 CPUs=$(nproc) RealMemory=1000 State=UNKNOWN
PartitionName=check Nodes=localhost Default=YES MaxTime=INFINITE State=UP
EOF

slurmctld -f "$SLURM_CONF" || fail "slurmctld did not start"
slurmd -f "$SLURM_CONF" -N localhost || fail "slurmd did not start"
echo "== cluster: slurmctld :$ctld_port, slurmd :$slurmd_port, $(nproc) CPUs, state in $WORK"
state=""
for _ in $(seq 60); do
  state=$(sinfo --noheader --nodes=localhost --format=%T 2>/dev/null || true)
  [ "$state" = "idle" ] && break
  sleep 0.5
done
[ "$state" = "idle" ] || fail "the node is not idle after 30 s (sinfo: '${state}')"
echo "== node idle after $(($(date +%s) - start)) s"

# Two inputs: the embedded synthetic scene at 32x32, two seeds (seconds each).
for k in 1 2; do
  "$AUDIT" --write-synthetic "$WORK/inputs/scene$k" --width 32 --height 32 --seed "$k" 2>>"$WORK/log/inputs.log" ||
    fail "audit --write-synthetic failed"
done

# The smallest run the pipeline accepts that still goes through every stage
# (the written scenes have no 3D points: --no-triangulate keeps COLMAP out of the
# scheduler's check).
export INPUTS="$WORK/inputs/scene1 $WORK/inputs/scene2" OUT="$WORK/out" AUDIT COMPLETION=oracle
export AUDIT_FLAGS="--no-triangulate --width 32 --height 32 --iters 30 --iters-g1 30 --views 36 --median-samples 4 --no-comparisons --no-static-diagnostics --checkpoint-every 0 --quiet"
# --array=1-2 (not the script's 0-3): the shard must come from the task index
# whatever the numbering starts at; --cpus-per-task=1 lets both tasks run at once.
submit_out=$(timeout 120 sbatch --wait --array=1-2 --cpus-per-task=1 --mem=500M \
  --output="$WORK/log/task-%A_%a.out" scripts/slurm/audit.sbatch) || {
  echo "$submit_out"
  for f in "$WORK"/log/task-*.out; do [ -f "$f" ] && { echo "-- $f"; cat "$f"; }; done
  fail "the array job failed"
}
JOB_ID=$(echo "$submit_out" | awk '/Submitted batch job/ {print $4}')
echo "== array job $JOB_ID done after $(($(date +%s) - start)) s"
for f in "$WORK"/log/task-*.out; do
  echo "-- $(basename "$f"): $(grep -m1 'shard .* from' "$f" || echo 'no shard line')"
done

# Each task ran its own shard, named by Slurm's index (not --shard).
for i in 1 2; do
  table="$WORK/out/audit-$i-of-2.json"
  [ -f "$table" ] || fail "no $table: task $i did not write its shard's table"
  python3 - "$table" "$i" <<'EOF' || fail "$table is not task $i's shard from Slurm"
import json, sys
t = json.load(open(sys.argv[1]))
a = t["audit"]
assert a["shard"] == sys.argv[2] + "/2" and a["shard_source"] == "slurm", a
assert len(t["rows"]) == 1 and t["rows"][0]["status"] == "ok", t["rows"]
EOF
done

# The merge: one run over every input, without a shard, reads both outputs.
(unset SLURM_ARRAY_TASK_ID JOB_COMPLETION_INDEX
 "$AUDIT" --inputs "$WORK/inputs/scene2" "$WORK/inputs/scene1" --report-only --out "$WORK/out" \
   >"$WORK/log/merge.out" 2>&1) || { cat "$WORK/log/merge.out"; fail "audit --report-only failed"; }
python3 - "$WORK/out/audit.json" <<'EOF' || fail "the merged table does not have both rows"
import json, sys
t = json.load(open(sys.argv[1]))
names = sorted(r["name"] for r in t["rows"])
assert names == ["scene1", "scene2"], names
assert all(r["status"] == "ok" for r in t["rows"]), t["rows"]
assert t["audit"]["shard_source"] == "none", t["audit"]
print("merged rows:", ", ".join(f'{r["name"]} ({r["status"]}, R1 gap PSNR {r["values"].get("R1_gap_psnr")})' for r in t["rows"]))
EOF
grep -A5 '^## Inputs' "$WORK/out/audit.md"
echo "check_slurm: passed in $(($(date +%s) - start)) s (two array tasks under slurmctld/slurmd, merged by --report-only)"
