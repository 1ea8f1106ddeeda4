#!/usr/bin/env bash
# A single-node Slurm on this machine, for `strings-bench run --executor slurm` and its tests
# (tests/integration/test_slurm.py). Idempotent: a Slurm already answering with its node idle is left as it is.
#
#   sudo bash scripts/slurm_local.sh          # install (Debian/Ubuntu apt), configure, start, wait for the node
#   sudo bash scripts/slurm_local.sh --stop   # stop the daemons it started
#
# It is also a worked example for a real cluster: every setting below is commented with what it does and what
# a cluster of several nodes would set instead. On a cluster the administrators run this part; strings-bench
# only needs `sbatch`, `squeue`, `scontrol` and `scancel` on the machine that runs `strings-bench run`, the same
# Python environment on every node, and the run folder on a file system every node mounts at the same path.
#
# Environment: SLURM_LOCAL_PARTITION (default "debug"), SLURM_LOCAL_WAIT (seconds to wait for the node, 60).
# Exit status: 0 with the node idle; 1 when it could not be installed or started (the reason on stderr).
set -euo pipefail
shopt -s extglob  # the *([0-9]) pattern below

PARTITION=${SLURM_LOCAL_PARTITION:-debug}
WAIT=${SLURM_LOCAL_WAIT:-60}
CONF_DIR=/etc/slurm
LOG_DIR=/var/log/slurm
say() { echo "[slurm-local] $*" >&2; }
die() { say "error: $*"; exit 1; }

stop_slurm() {  # and wait until the daemons are gone, so that a restart does not find the old ones
  local pids=() pidfile
  for pidfile in /run/slurmd.pid /run/slurmctld.pid; do
    [ -f "$pidfile" ] && pids+=("$(cat "$pidfile")")
  done
  [ ${#pids[@]} -gt 0 ] || return 0
  kill "${pids[@]}" 2>/dev/null || true
  for _ in $(seq 30); do kill -0 "${pids[@]}" 2>/dev/null || break; sleep 0.5; done
  rm -f /run/slurmd.pid /run/slurmctld.pid
}
stop() {
  stop_slurm
  for pidfile in /run/munge/munged.pid; do
    [ -f "$pidfile" ] && kill "$(cat "$pidfile")" 2>/dev/null || true
  done
  say "stopped"
}
[ "${1:-}" = "--stop" ] && { stop; exit 0; }

node_state() { sinfo -h -N -o '%T' 2>/dev/null | head -1 || true; }
OURS="Written by strings-bench scripts/slurm_local.sh"
# A Slurm that is up and not configured by this script (a cluster's own) is left alone.
if command -v sinfo >/dev/null && [ "$(node_state)" = "idle" ] && ! grep -qs "$OURS" "$CONF_DIR/slurm.conf"; then
  say "Slurm is up: $(sinfo -h -o '%P %D node(s) %T' | head -1)"
  exit 0
fi

[ "$(id -u)" = 0 ] || die "run as root (it installs packages and starts daemons)"

# ---- 1. packages: the controller (slurmctld), the node daemon (slurmd), the client commands, and munge, which
# signs every message between them. On a cluster: slurmctld on the head node, slurmd on every compute node,
# slurm-client wherever users submit, munge everywhere (with the same /etc/munge/munge.key on every machine).
if ! command -v slurmctld >/dev/null || ! command -v slurmd >/dev/null || ! command -v munged >/dev/null \
   || ! command -v sbatch >/dev/null; then
  command -v apt-get >/dev/null || die "no apt-get here: install slurmctld, slurmd, slurm-client and munge by hand"
  say "installing slurmctld slurmd slurm-client munge (apt-get)"
  export DEBIAN_FRONTEND=noninteractive
  apt-get update -qq || die "apt-get update failed"
  apt-get install -y -qq --no-install-recommends slurmctld slurmd slurm-client munge >/dev/null \
    || die "apt-get install slurmctld slurmd slurm-client munge failed"
fi

# ---- 2. munge: one key shared by every machine of the cluster (the package made one for this machine).
install -d -o munge -g munge -m 0700 /etc/munge /var/lib/munge /var/log/munge
install -d -o munge -g munge -m 0755 /run/munge
if [ ! -s /etc/munge/munge.key ]; then
  dd if=/dev/urandom of=/etc/munge/munge.key bs=1 count=1024 status=none
fi
chown munge:munge /etc/munge/munge.key && chmod 0400 /etc/munge/munge.key
if ! munge -n 2>/dev/null | unmunge >/dev/null 2>&1; then
  # No systemd in a container: start the daemon directly, as its own user.
  runuser -u munge -- /usr/sbin/munged || die "munged did not start (see /var/log/munge/munged.log)"
  for _ in $(seq 20); do munge -n 2>/dev/null | unmunge >/dev/null 2>&1 && break; sleep 0.5; done
  munge -n | unmunge >/dev/null 2>&1 || die "munge does not answer (see /var/log/munge/munged.log)"
fi

# ---- 3. slurm.conf: this machine is both the controller and the only compute node.
HOST=$(hostname -s)
# The node's real CPUs and memory, as slurmd itself detects them ("NodeName=vm CPUs=2 ... RealMemory=24105").
# A node declared larger than it is would be drained at registration; smaller wastes it.
NODE_LINE=$(slurmd -C | head -1)
NODE_LINE=${NODE_LINE/NodeName=* CPUs=/NodeName=$HOST CPUs=}
# Leave 1 GiB of memory to the system, so that a job asking for the whole node does not starve the daemons.
MEM=$(sed -n 's/.*RealMemory=\([0-9]*\).*/\1/p' <<<"$NODE_LINE")
MEM=$(( MEM > 2048 ? MEM - 1024 : MEM ))
NODE_LINE=${NODE_LINE/RealMemory=*([0-9])/RealMemory=$MEM}
CPUS=$(sed -n 's/.*CPUs=\([0-9]*\).*/\1/p' <<<"$NODE_LINE")
install -d -o slurm -g slurm -m 0755 /var/spool/slurmctld /var/spool/slurmd "$LOG_DIR"
install -d "$CONF_DIR"
cat > "$CONF_DIR/slurm.conf.new" <<EOF
# $OURS: a single-node Slurm on $HOST.
ClusterName=strings-bench-local
SlurmctldHost=$HOST                 # the head node; a cluster may list a backup controller on a second line
SlurmUser=slurm                     # the controller runs as this user; slurmd runs as root (it starts jobs as their users)
AuthType=auth/munge
StateSaveLocation=/var/spool/slurmctld  # on a cluster: a folder the backup controller shares
SlurmdSpoolDir=/var/spool/slurmd
SlurmctldPidFile=/run/slurmctld.pid
SlurmdPidFile=/run/slurmd.pid
SlurmctldLogFile=$LOG_DIR/slurmctld.log
SlurmdLogFile=$LOG_DIR/slurmd.log
# How slurmd follows a job's processes and confines them. In a container without systemd there are no cgroups
# to delegate: linuxproc follows processes by their parent ids, task/none binds nothing. A real cluster uses
# ProctrackType=proctrack/cgroup and TaskPlugin=task/cgroup,task/affinity (with a cgroup.conf), so that a job
# cannot use more CPUs, memory or GPUs than it asked for.
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
# No accounting database (slurmdbd): sacct has nothing to read. strings-bench follows its jobs with squeue and
# scontrol only, which every Slurm has. A cluster usually runs slurmdbd (AccountingStorageType=accounting_storage/slurmdbd).
AccountingStorageType=accounting_storage/none
# Schedule single cores and memory, so that several one-CPU jobs of an array share the node.
SelectType=select/cons_tres
SelectTypeParameters=CR_Core_Memory
# A job that does not say how much memory it needs (no --mem) gets its CPUs' share of the node, not the whole node:
# without this, one job holds all the memory and the others of an array wait ("Resources") however many cores are free.
DefMemPerCPU=$(( MEM / CPUS ))
MpiDefault=none
ReturnToService=2                   # a node that was down comes back by itself once its slurmd answers
SlurmdTimeout=60
MinJobAge=600                       # scontrol still shows an ended job for 10 minutes (its final state)
KillWait=5                          # seconds between SIGTERM and SIGKILL when a job is cancelled or times out
# Preemption is off here. A cluster that preempts (PreemptType=preempt/partition_prio or preempt/qos) with
# PreemptMode=REQUEUE puts a preempted job back in the queue; strings-bench's jobs then continue from their
# saved training state (docs/guide/cluster.md, "Slurm").
# GPUs: a GPU node declares them here and in gres.conf, e.g.
#   GresTypes=gpu
#   NodeName=gpu01 CPUs=32 RealMemory=256000 Gres=gpu:4
# and gres.conf: NodeName=gpu01 Name=gpu File=/dev/nvidia[0-3]. Then --slurm-gpus-per-task 1 gives each job one.
$NODE_LINE State=UNKNOWN
PartitionName=$PARTITION Nodes=$HOST Default=YES MaxTime=INFINITE State=UP
EOF
# No cgroup.conf: Slurm 22.05 (Debian 12) detects the cgroup version by itself and uses it for nothing with the
# plugins above. (Slurm 23.02 and later accept CgroupPlugin=disabled there, for containers without cgroups.)
changed=0
for f in slurm.conf; do
  if ! cmp -s "$CONF_DIR/$f.new" "$CONF_DIR/$f"; then mv "$CONF_DIR/$f.new" "$CONF_DIR/$f"; changed=1; else rm "$CONF_DIR/$f.new"; fi
done

# ---- 4. start the daemons (directly: no systemd in a container; on a cluster `systemctl enable --now slurmctld`
# on the head node and `systemctl enable --now slurmd` on each compute node).
if [ "$changed" = 1 ]; then stop_slurm; fi  # the new configuration: restart (jobs in the queue are kept)
running() { [ -f "$1" ] && kill -0 "$(cat "$1")" 2>/dev/null; }
running /run/slurmctld.pid || /usr/sbin/slurmctld -i || die "slurmctld did not start (see $LOG_DIR/slurmctld.log)"
running /run/slurmd.pid || /usr/sbin/slurmd || die "slurmd did not start (see $LOG_DIR/slurmd.log)"

# ---- 5. wait until the node is idle (registered with the controller and free for jobs).
say "waiting for node $HOST to be idle (up to $WAIT s)"
end=$(( $(date +%s) + WAIT ))
while [ "$(date +%s)" -lt "$end" ]; do
  state=$(node_state)
  case "$state" in
    idle) say "Slurm is up: $(sinfo -h -o '%P %D node(s) %c CPUs %m MB %T' | head -1)"; exit 0 ;;
    down*|drain*) scontrol update nodename="$HOST" state=resume 2>/dev/null || true ;;
  esac
  sleep 1
done
die "node $HOST is '$(node_state)' after $WAIT s (see $LOG_DIR/slurmctld.log and $LOG_DIR/slurmd.log)"
