#!/usr/bin/env bash
# A one-node Slurm cluster on this machine, to try the batch scripts of this folder
# for real (Debian 12, as root): munge, slurmctld and slurmd with a configuration in
# $DIR (default /tmp/mpmcg-slurm). Not for production: no accounting, no cgroups.
#
#   scripts/slurm/local_slurm.sh start     # installs slurm-wlm and munge if missing
#   export SLURM_CONF=/tmp/mpmcg-slurm/slurm.conf
#   sbatch ... ; squeue ; sinfo
#   scripts/slurm/local_slurm.sh stop
#
# The node offers this machine's cores; OverSubscribe lets a job ask for more tasks
# than that (`sbatch --ntasks=4` on 2 cores), as the multi-rank tests do with mpirun.
set -euo pipefail

DIR=${DIR:-/tmp/mpmcg-slurm}
cmd=${1:-start}

if [[ $(id -u) != 0 ]]; then
    echo "error: run as root (slurmd starts jobs as their users)" >&2
    exit 2
fi

stop() {
    for d in slurmd slurmctld munged; do
        if [[ -f $DIR/$d.pid ]]; then
            kill "$(cat "$DIR/$d.pid")" 2>/dev/null || true
            rm -f "$DIR/$d.pid"
        fi
    done
}

case $cmd in
stop)
    stop
    exit 0
    ;;
start) ;;
*)
    echo "usage: $0 start|stop" >&2
    exit 2
    ;;
esac

if ! command -v slurmctld >/dev/null || ! command -v munged >/dev/null; then
    DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends slurm-wlm munge
fi

stop
mkdir -p "$DIR"/{spool,state,log}
host=$(hostname -s)
# CPUs, sockets, cores and memory as slurmd sees them.
node=$(slurmd -C | head -1)
cpus=$(nproc)
cat >"$DIR/slurm.conf" <<EOF
ClusterName=local
SlurmctldHost=$host
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
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
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
MpiDefault=none
ReturnToService=2
# Requeue/resubmit tests: a job that ends at its limit is signalled, then killed.
KillWait=30
$node State=UNKNOWN
PartitionName=debug Nodes=$host Default=YES MaxTime=INFINITE State=UP OverSubscribe=FORCE:4
EOF

# munged runs as the munge user, with its key and socket directory.
install -d -o munge -g munge -m 0755 /run/munge
if [[ ! -s /etc/munge/munge.key ]]; then
    mungekey --create
    chown munge:munge /etc/munge/munge.key
fi
runuser -u munge -- /usr/sbin/munged
cp /run/munge/munged.pid "$DIR/munged.pid"

export SLURM_CONF=$DIR/slurm.conf
slurmctld
slurmd
for _ in $(seq 30); do
    if sinfo -h -o %T 2>/dev/null | grep -qx idle; then
        echo "one-node Slurm up ($cpus CPUs): export SLURM_CONF=$SLURM_CONF"
        exit 0
    fi
    sleep 1
done
echo "error: the node did not become idle; see $DIR/log" >&2
sinfo >&2 || true
exit 1
