#!/usr/bin/env bash
# A one-node SLURM cluster on this machine, for the cluster test (tests/workflow/test_cluster.py).
#
#   sudo .ci/start_slurm.sh          start it (does nothing if it is already up)
#   sudo .ci/start_slurm.sh stop     stop the daemons this script started
#
# Needs root and Debian's `slurm-wlm` and `munge` packages (`apt-get install slurm-wlm munge`).
# Everything lives in one private directory (default /var/lib/ssmobs-slurm, or $SSMOBS_SLURM_DIR):
# the munge key and socket, slurm.conf, state, logs. No accounting database: job states come
# from `squeue` (the executor plugin's `--slurm-status-command squeue`), so slurmctld keeps
# finished jobs for MinJobAge seconds. One partition `ssmobs` (the default) with
# $SSMOBS_SLURM_CPUS CPUs (default 2). The SLURM client commands find the cluster through
# /etc/slurm/slurm.conf, which is linked to ours if it does not exist yet; otherwise
# `export SLURM_CONF=$SSMOBS_SLURM_DIR/slurm.conf`.
set -euo pipefail

DIR=${SSMOBS_SLURM_DIR:-/var/lib/ssmobs-slurm}
CPUS=${SSMOBS_SLURM_CPUS:-2}
CONF=$DIR/slurm.conf
SOCKET=$DIR/munge/munge.socket
export SLURM_CONF=$CONF

die() { echo "start_slurm: $*" >&2; exit 1; }

running() {  # pid file -> is that process alive?
  [[ -s $1 ]] && kill -0 "$(cat "$1")" 2>/dev/null
}

stop() {
  for pidfile in "$DIR/slurmd.pid" "$DIR/slurmctld.pid" "$DIR/munge/munged.pid"; do
    if running "$pidfile"; then
      kill "$(cat "$pidfile")"
      echo "start_slurm: stopped $(basename "$pidfile" .pid)"
    fi
  done
}

if [[ ${1:-start} == stop ]]; then
  stop
  exit 0
fi
[[ ${1:-start} == start ]] || die "usage: $0 [start|stop]"
[[ $(id -u) == 0 ]] || die "needs root (slurmd starts jobs as their user)"
for cmd in munged slurmctld slurmd sinfo scontrol sbatch squeue; do
  command -v "$cmd" >/dev/null || die "'$cmd' not found: apt-get install slurm-wlm munge"
done

node_ready() {
  sinfo --noheader -o %T 2>/dev/null | grep -Eq '^(idle|mixed|allocated|completing)'
}

if running "$DIR/munge/munged.pid" && running "$DIR/slurmctld.pid" \
   && running "$DIR/slurmd.pid" && node_ready; then
  echo "start_slurm: already running ($CONF)"
  exit 0
fi

host=$(hostname -s)
mkdir -p "$DIR"/{munge,state,spool,log}
chmod 700 "$DIR/munge"

# munge: a private key, socket and daemon, so a system-wide munge is left alone.
if [[ ! -s $DIR/munge/munge.key ]]; then
  dd if=/dev/urandom of="$DIR/munge/munge.key" bs=1024 count=1 status=none
fi
chmod 400 "$DIR/munge/munge.key"
if ! running "$DIR/munge/munged.pid"; then
  rm -f "$SOCKET" "$SOCKET.lock"
  munged --force --key-file="$DIR/munge/munge.key" --socket="$SOCKET" \
         --pid-file="$DIR/munge/munged.pid" --log-file="$DIR/log/munged.log" \
         --seed-file="$DIR/munge/munged.seed"
fi

# The node's memory as slurmd sees it (jobs ask for up to a few GB; memory is not a
# consumable resource here, SelectTypeParameters=CR_CPU, so jobs are packed by CPU only).
mem=$(slurmd -C | sed -n 's/.*RealMemory=\([0-9]*\).*/\1/p')
cat > "$CONF.new" <<EOF
# Written by .ci/start_slurm.sh: a one-node cluster for the ssmobs cluster test.
ClusterName=ssmobs
SlurmctldHost=$host(127.0.0.1)
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
CredType=cred/munge
AuthInfo=socket=$SOCKET
StateSaveLocation=$DIR/state
SlurmdSpoolDir=$DIR/spool
SlurmctldPidFile=$DIR/slurmctld.pid
SlurmdPidFile=$DIR/slurmd.pid
SlurmctldLogFile=$DIR/log/slurmctld.log
SlurmdLogFile=$DIR/log/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
JobCompType=jobcomp/none
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_CPU
ReturnToService=2
# squeue reports a finished job's state for MinJobAge seconds: the executor plugin needs at
# least 3x its first status-check delay (40 s by default).
MinJobAge=3600
NodeName=$host NodeAddr=127.0.0.1 CPUs=$CPUS RealMemory=$mem State=UNKNOWN
PartitionName=ssmobs Nodes=$host Default=YES MaxTime=INFINITE State=UP
EOF
mv "$CONF.new" "$CONF"
if [[ ! -e /etc/slurm/slurm.conf ]]; then
  mkdir -p /etc/slurm
  ln -s "$CONF" /etc/slurm/slurm.conf
elif [[ $(readlink -f /etc/slurm/slurm.conf) != "$(readlink -f "$CONF")" ]]; then
  echo "start_slurm: /etc/slurm/slurm.conf is another cluster's; use: export SLURM_CONF=$CONF" >&2
fi

running "$DIR/slurmctld.pid" || slurmctld -f "$CONF"
running "$DIR/slurmd.pid" || slurmd -f "$CONF" -N "$host"

for _ in $(seq 60); do
  if node_ready; then
    sinfo
    echo "start_slurm: up ($CONF)"
    exit 0
  fi
  # A node that was down (e.g. a restart of slurmd) is set back in service.
  if sinfo --noheader -o %T 2>/dev/null | grep -Eq '^(down|drained|draining)'; then
    scontrol update nodename="$host" state=resume 2>/dev/null || true
  fi
  sleep 1
done
sinfo || true
tail -n 20 "$DIR/log/slurmctld.log" "$DIR/log/slurmd.log" >&2 || true
die "the node did not become ready within 60 s (logs in $DIR/log)"
