#!/usr/bin/env bash
# CI: the guide's Slurm job-array recipe (docs/guide/large-meshes.md, "Spread over machines"),
# run on a real Slurm. Installs Debian's slurm-wlm and munge when absent, starts a single-node
# Slurm on this machine (a munge key, /etc/slurm/slurm.conf with this host as controller and
# only node, munged, slurmctld, slurmd), submits the recipe's array job with `sbatch --wait`,
# merges the parts with `touchfem precompute --merge` and checks the merged file byte for byte
# against the unsharded one. Slurm does the scheduling; nothing here imitates it.
#
# Idempotent: a Slurm that this script started and that still answers is reused; a stale one
# (config changed, daemon dead or not answering) is stopped by its pid files and started anew.
# The daemons stay up afterwards; `scripts/slurm-precompute.sh --stop` stops them (and munged).
# Needs root or sudo. TOUCHFEM_BIN names the binary to use (default: the debug build, which
# .ci/run has already made).
set -euo pipefail
cd "$(dirname "$0")/.."
export LC_ALL=C

SUDO=""
if [ "$(id -u)" != 0 ]; then SUDO="sudo"; fi
conf=/etc/slurm/slurm.conf
marker="# Written by touchfem's scripts/slurm-precompute.sh: a single-node Slurm for CI."
ctld_pid=/run/slurmctld.pid
slurmd_pid=/run/slurmd.pid
work=target/slurm-precompute
host=$(hostname -s)

# Microseconds now; seconds since $1 (a now), to the hundredth.
now() { echo "${EPOCHREALTIME/./}"; }
since() { awk -v a="$1" -v b="$(now)" 'BEGIN { printf "%.2f", (b - a) / 1e6 }'; }

fail() {
  echo "slurm-precompute: $*" >&2
  exit 1
}

# Stops the daemon whose pid file is $1 if it is the program $2 (by its id, nothing else).
stop_pidfile() {
  local file=$1 prog=$2 pid
  [ -s "$file" ] || return 0
  pid=$($SUDO cat "$file")
  if [ "$(cat "/proc/$pid/comm" 2>/dev/null)" = "$prog" ]; then
    echo "stopping $prog (pid $pid)" >&2
    $SUDO kill "$pid" 2>/dev/null || true
    for _ in $(seq 50); do
      [ -e "/proc/$pid" ] || break
      sleep 0.2
    done
    if [ -e "/proc/$pid" ]; then $SUDO kill -9 "$pid" 2>/dev/null || true; fi
  fi
  $SUDO rm -f "$file"
}

if [ "${1:-}" = "--stop" ]; then
  stop_pidfile "$slurmd_pid" slurmd
  stop_pidfile "$ctld_pid" slurmctld
  stop_pidfile /run/munge/munged.pid munged
  exit 0
fi

t_all=$(now)

# 1. The packages.
t=$(now)
if ! command -v sbatch >/dev/null 2>&1 || ! command -v slurmctld >/dev/null 2>&1 \
  || ! command -v slurmd >/dev/null 2>&1 || ! command -v munged >/dev/null 2>&1; then
  echo "installing slurm-wlm and munge..." >&2
  export DEBIAN_FRONTEND=noninteractive
  $SUDO apt-get update -qq
  $SUDO apt-get install -y -qq --no-install-recommends slurm-wlm munge >/dev/null
fi
t_install=$(since "$t")

# 2. Munge: a key (Debian's postinst makes one; made here if missing) and the daemon.
t=$(now)
if ! $SUDO test -s /etc/munge/munge.key; then
  echo "creating the munge key" >&2
  $SUDO mungekey --create --keyfile=/etc/munge/munge.key
fi
$SUDO chown munge:munge /etc/munge/munge.key
$SUDO chmod 0400 /etc/munge/munge.key
if ! munge -n 2>/dev/null | unmunge >/dev/null 2>&1; then
  echo "starting munged" >&2
  $SUDO install -d -o munge -g munge -m 0755 /run/munge
  # munged refuses root; it daemonises itself. No stdio of ours stays open in it.
  $SUDO runuser -u munge -- /usr/sbin/munged </dev/null >/dev/null 2>&1 \
    || fail "munged did not start; see /var/log/munge/munged.log"
  deadline=$((SECONDS + 10))
  until munge -n 2>/dev/null | unmunge >/dev/null 2>&1 || [ $SECONDS -ge $deadline ]; do
    sleep 0.2
  done
  munge -n 2>/dev/null | unmunge >/dev/null 2>&1 \
    || fail "munge does not answer after 10 s; see /var/log/munge/munged.log"
fi

# 3. Slurm: this host as controller and only node. The node line is slurmd's own view of the
# hardware (CPUs, sockets, cores, memory), so the node is never drained for a mismatch.
node_line=$(slurmd -C | sed -n 1p)
case "$node_line" in
  NodeName=*CPUs=*) ;;
  *) fail "slurmd -C printed no node line: $node_line" ;;
esac
want=$(cat <<EOF
$marker
ClusterName=touchfem
SlurmctldHost=$host
SlurmUser=slurm
AuthType=auth/munge
StateSaveLocation=/var/lib/slurm/slurmctld
SlurmdSpoolDir=/var/lib/slurm/slurmd
SlurmctldPidFile=$ctld_pid
SlurmdPidFile=$slurmd_pid
SlurmctldLogFile=/var/log/slurm/slurmctld.log
SlurmdLogFile=/var/log/slurm/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
MpiDefault=none
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_CPU
ReturnToService=2
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
$node_line State=UNKNOWN
PartitionName=debug Nodes=ALL Default=YES MaxTime=INFINITE State=UP
EOF
)
if [ -e "$conf" ] && ! head -n 1 "$conf" | grep -qxF "$marker"; then
  fail "$conf exists and was not written by this script; not touching it (this check wants a Slurm of its own: run it where none is configured)"
fi

ctld_up() { timeout 5 scontrol ping 2>/dev/null | grep "is UP" >/dev/null; }
node_state() { timeout 5 sinfo -h -n "$host" -o %T 2>/dev/null | sed -n 1p || true; }
healthy() {
  ctld_up || return 1
  case "$(node_state)" in idle | mixed | allocated | completing) return 0 ;; *) return 1 ;; esac
}

if [ "$(cat "$conf" 2>/dev/null)" = "$want" ] && healthy; then
  echo "reusing the running Slurm ($(sinfo -h -o '%P %D %T' | sed -n 1p))" >&2
else
  stop_pidfile "$slurmd_pid" slurmd
  stop_pidfile "$ctld_pid" slurmctld
  printf '%s\n' "$want" | $SUDO tee "$conf" >/dev/null
  $SUDO install -d -o slurm -g slurm /var/lib/slurm/slurmctld /var/lib/slurm/slurmd /var/log/slurm
  echo "starting slurmctld and slurmd" >&2
  # Both daemonise; -c starts without the jobs of an earlier run.
  $SUDO slurmctld -c </dev/null >/dev/null 2>&1 || fail "slurmctld did not start; see /var/log/slurm/slurmctld.log"
  deadline=$((SECONDS + 30))
  until ctld_up || [ $SECONDS -ge $deadline ]; do sleep 0.2; done
  ctld_up || { $SUDO tail -n 20 /var/log/slurm/slurmctld.log >&2 || true; fail "slurmctld does not answer after 30 s"; }
  $SUDO slurmd -c </dev/null >/dev/null 2>&1 || fail "slurmd did not start; see /var/log/slurm/slurmd.log"
  resumed=""
  deadline=$((SECONDS + 60))
  while [ $SECONDS -lt $deadline ]; do
    state=$(node_state)
    case "$state" in
      idle | mixed | allocated | completing) break ;;
      down* | drain* | fail*)
        if [ -z "$resumed" ]; then
          echo "node $host is $state; resuming it" >&2
          $SUDO scontrol update nodename="$host" state=resume || true
          resumed=1
        fi
        ;;
    esac
    sleep 0.2
  done
  if ! healthy; then
    sinfo -N -l >&2 || true
    $SUDO tail -n 20 /var/log/slurm/slurmd.log >&2 || true
    fail "node $host is not idle after 60 s (state: ${state:-none})"
  fi
fi
t_daemons=$(since "$t")

# 4. The binary and the unsharded file.
t=$(now)
if [ -n "${TOUCHFEM_BIN:-}" ]; then
  bin=$TOUCHFEM_BIN
else
  cargo build --quiet --features app --bin touchfem
  bin="${CARGO_TARGET_DIR:-target}/debug/touchfem"
fi
[ -x "$bin" ] || fail "no touchfem binary at $bin"
t_build=$(since "$t")
bindir=$(cd "$(dirname "$bin")" && pwd)
export PATH="$bindir:$PATH"
rm -rf "$work"
mkdir -p "$work/parts" "$work/logs" "$work/cache"
export TOUCHFEM_CACHE_DIR="$PWD/$work/cache"
start=$(now)
touchfem precompute scenes/palpate.toml --out "$work/palpate.tfc" >/dev/null \
  || fail "the unsharded precompute failed"
t_whole=$(since "$start")

# 5. The recipe: an array job of 4 shards submitted from the repository root, then one merge.
# The guide shows these lines word for word; checked here so that it cannot drift.
cat >"$work/precompute.sbatch" <<'EOF'
#!/bin/bash
#SBATCH --array=1-4 --cpus-per-task=1 --mem=1G --time=5
#SBATCH --output=target/slurm-precompute/logs/%A_%a.out
touchfem precompute scenes/palpate.toml --shard ${SLURM_ARRAY_TASK_ID}/4 --out target/slurm-precompute/parts/palpate.part-${SLURM_ARRAY_TASK_ID}
EOF
merge='touchfem precompute --merge target/slurm-precompute/parts/palpate.part-* --out target/slurm-precompute/palpate-merged.tfc'
guide=docs/guide/large-meshes.md
while IFS= read -r line; do
  grep -qxF -- "$line" "$guide" || fail "$guide no longer shows the tested recipe's line: $line"
done < <(cat "$work/precompute.sbatch"; echo "$merge")
start=$(now)
rc=0
timeout 300 sbatch --wait --parsable "$work/precompute.sbatch" >"$work/jobid" || rc=$?
if [ "$rc" != 0 ]; then
  for log in "$work"/logs/*.out; do
    [ -e "$log" ] && sed "s|^|  $(basename "$log" .out): |" "$log" >&2
  done
  squeue >&2 || true
  if [ "$rc" = 124 ]; then
    fail "the array job did not finish in 300 s (job $(cat "$work/jobid" 2>/dev/null))"
  fi
  fail "the array job failed: sbatch --wait exited $rc, the highest exit status of its tasks (job $(cat "$work/jobid" 2>/dev/null))"
fi
t_array=$(since "$start")
ls "$work"/parts/palpate.part-{1,2,3,4} >/dev/null || fail "the array job left parts missing"
# What each task did, and when Slurm ran it (two at a time on two CPUs).
for task in 1 2 3 4; do
  when=$(scontrol show job "$(cat "$work/jobid")_$task" 2>/dev/null | grep -o 'StartTime=[^ ]*' || true)
  echo "  task $task ${when#StartTime=}: $(cat "$work"/logs/*_$task.out)" >&2
done
start=$(now)
$merge >/dev/null || fail "the merge failed"
t_merge=$(since "$start")
cmp "$work/palpate.tfc" "$work/palpate-merged.tfc" \
  || fail "the merged file differs from the unsharded one"

printf 'slurm-precompute: Slurm %s on %s (%s): install %.1f s, munge and Slurm up %.1f s, build %.1f s, unsharded %.2f s, array job 1-4 (job %s) %.2f s, merge %.2f s, merged = unsharded (%d bytes); %.1f s in all\n' \
  "$(sinfo -V | cut -d' ' -f2)" "$host" "${node_line#NodeName=* }" "$t_install" "$t_daemons" "$t_build" \
  "$t_whole" "$(cat "$work/jobid")" "$t_array" "$t_merge" \
  "$(stat -c %s "$work/palpate.tfc")" "$(since "$t_all")"
