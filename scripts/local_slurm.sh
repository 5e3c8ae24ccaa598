#!/usr/bin/env bash
# A one-node Slurm on this machine (Debian's slurm-wlm + munge), to run `neuraldem datagen executor=slurm` and
# `neuraldem train -m hydra/launcher=slurm` against a real sbatch/srun/squeue without a cluster.
#   bash scripts/local_slurm.sh start   # installs slurm-wlm + munge if missing (apt-get), starts munged,
#                                       # slurmctld and slurmd with a private config in $SLURM_LOCAL_DIR
#   export SLURM_CONF=${SLURM_LOCAL_DIR:-/tmp/neuraldem-slurm}/slurm.conf   # then sbatch/squeue use it
#   bash scripts/local_slurm.sh stop
# One partition `debug` with this machine's cores; no job accounting (sacct answers that it is disabled, as on
# clusters without slurmdbd). Needs root (slurmd starts the jobs' processes).
set -euo pipefail
DIR=${SLURM_LOCAL_DIR:-/tmp/neuraldem-slurm}
CONF=$DIR/slurm.conf
say() { printf '[local-slurm] %s\n' "$*"; }

start() {
  [ "$(id -u)" -eq 0 ] || { say "needs root (slurmd runs the jobs)"; exit 2; }
  if ! command -v slurmctld >/dev/null || ! command -v munged >/dev/null; then
    say "installing slurm-wlm and munge with apt-get"
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq slurm-wlm munge >/dev/null
  fi
  mkdir -p "$DIR/state" "$DIR/spool"
  local host cpus mem
  host=$(hostname -s)
  # the machine's cores: plain nproc answers $OMP_NUM_THREADS when that is set (.ci/run sets it to 1), and a
  # one-CPU node never starts the two-task DDP job
  cpus=$(env -u OMP_NUM_THREADS -u OMP_THREAD_LIMIT nproc)
  mem=$(( $(awk '/MemTotal/ {print $2}' /proc/meminfo) / 1024 * 8 / 10 ))
  local old=""
  [ -f "$CONF" ] && old=$(cat "$CONF")
  cat > "$CONF" <<EOF
ClusterName=neuraldem-local
SlurmctldHost=$host
SlurmUser=root
AuthType=auth/munge
StateSaveLocation=$DIR/state
SlurmdSpoolDir=$DIR/spool
SlurmctldPidFile=$DIR/slurmctld.pid
SlurmdPidFile=$DIR/slurmd.pid
SlurmctldLogFile=$DIR/slurmctld.log
SlurmdLogFile=$DIR/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SchedulerType=sched/builtin
SelectType=select/cons_tres
SelectTypeParameters=CR_Core_Memory
DefMemPerCPU=1024
ReturnToService=2
MpiDefault=none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
NodeName=$host CPUs=$cpus RealMemory=$mem State=UNKNOWN
PartitionName=debug Nodes=$host Default=YES MaxTime=INFINITE State=UP
EOF
  # daemons left running with another configuration (other core count, memory, host) would keep it: restart them
  if [ "$old" != "$(cat "$CONF")" ] && { pgrep -x slurmctld >/dev/null || pgrep -x slurmd >/dev/null; }; then
    say "the configuration changed: restarting slurmctld and slurmd"
    stop
  fi
  pgrep -x munged >/dev/null || { mkdir -p /run/munge && chown munge:munge /run/munge 2>/dev/null || true
                                  su -s /bin/sh munge -c munged 2>/dev/null || munged --force; }
  # -c: forget jobs a stopped cluster still holds (their slurmd is gone; a stale pending one blocks the node)
  pgrep -x slurmctld >/dev/null || SLURM_CONF=$CONF slurmctld -c
  pgrep -x slurmd >/dev/null || SLURM_CONF=$CONF slurmd
  for _ in $(seq 30); do
    if SLURM_CONF=$CONF sinfo -h -o '%t' 2>/dev/null | grep -qE '^(idle|mix|alloc)'; then
      SLURM_CONF=$CONF sinfo
      say "running; use it with: export SLURM_CONF=$CONF"
      return 0
    fi
    sleep 1
  done
  say "the node did not come up in 30 s: see $DIR/slurmctld.log and $DIR/slurmd.log"
  return 1
}

stop() {
  pkill -x slurmd || true
  pkill -x slurmctld || true
  for _ in $(seq 20); do pgrep -x slurmd >/dev/null || pgrep -x slurmctld >/dev/null || break; sleep 0.5; done
  say "stopped (munged left running)"
}

case "${1:-}" in
  start) start ;;
  stop) stop ;;
  *) echo "usage: $0 start|stop" >&2; exit 2 ;;
esac
