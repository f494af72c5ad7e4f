#!/usr/bin/env bash
# A throw-away one-node Slurm cluster for tests: munged, slurmctld and slurmd from Debian's
# packages (slurmctld, slurmd, slurm-client, munge; `./setup.sh --tests` installs them), run as
# root with every file (config, key, sockets, state, logs) under one temporary folder and on
# ports of their own, so nothing of the machine's own configuration is read or changed.
#
#   tests/slurm/cluster.sh start DIR   # prints the SLURM_CONF to export; waits for the node
#   tests/slurm/cluster.sh stop DIR    # stops every daemon started in DIR
set -euo pipefail
cmd=${1:?start or stop}
dir=$(realpath -m "${2:?folder}")
say() { echo "cluster: $*" >&2; }

stop() {
  for d in slurmd slurmctld munged; do
    local pidf="$dir/run/$d.pid"
    [ -f "$pidf" ] || continue
    local pid; pid=$(cat "$pidf")
    kill "$pid" 2>/dev/null || true
    for _ in $(seq 50); do kill -0 "$pid" 2>/dev/null || break; sleep 0.1; done
    kill -9 "$pid" 2>/dev/null || true
    rm -f "$pidf"
  done
}

if [ "$cmd" = stop ]; then stop; exit 0; fi
[ "$cmd" = start ] || { say "unknown command $cmd"; exit 2; }
for b in munged slurmctld slurmd sbatch sinfo; do
  command -v "$b" >/dev/null || { say "$b not found: run ./setup.sh --tests"; exit 1; }
done
[ "$(id -u)" -eq 0 ] || { say "must run as root (slurmd starts jobs as their user)"; exit 1; }

mkdir -p "$dir"/{etc,run,log,munge,spool/ctld,spool/d}
chmod 700 "$dir/munge"
head -c 1024 /dev/urandom > "$dir/munge/munge.key"
chmod 400 "$dir/munge/munge.key"
sock="$dir/munge/munge.socket"
munged --force --socket="$sock" --key-file="$dir/munge/munge.key" \
  --pid-file="$dir/run/munged.pid" --log-file="$dir/log/munged.log" \
  --seed-file="$dir/munge/munged.seed"

# Ports of our own, away from a real cluster's 6817/6818.
base=$(( 20000 + RANDOM % 20000 ))
host=$(hostname -s)
cpus=$(nproc)
mem=$(( $(awk '/MemTotal/ {print $2}' /proc/meminfo) / 1024 / 2 ))
cat > "$dir/etc/slurm.conf" <<CONF
ClusterName=reframe-test
SlurmctldHost=$host(127.0.0.1)
SlurmctldPort=$base
SlurmdPort=$(( base + 1 ))
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
AuthInfo=socket=$sock
CryptoType=crypto/munge
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
MpiDefault=none
ReturnToService=2
JobCompType=jobcomp/none
AccountingStorageType=accounting_storage/none
StateSaveLocation=$dir/spool/ctld
SlurmdSpoolDir=$dir/spool/d
SlurmctldPidFile=$dir/run/slurmctld.pid
SlurmdPidFile=$dir/run/slurmd.pid
SlurmctldLogFile=$dir/log/slurmctld.log
SlurmdLogFile=$dir/log/slurmd.log
SlurmctldParameters=enable_configless
SchedulerParameters=sched_interval=1
MessageTimeout=10
NodeName=$host NodeAddr=127.0.0.1 CPUs=$cpus RealMemory=$mem State=UNKNOWN
PartitionName=test Nodes=ALL Default=YES MaxTime=INFINITE State=UP
CONF
export SLURM_CONF="$dir/etc/slurm.conf"
slurmctld -i -f "$SLURM_CONF"
slurmd -f "$SLURM_CONF"
for _ in $(seq 300); do
  state=$(sinfo -h -o %T 2>/dev/null || true)
  if [ "$state" = idle ]; then echo "$SLURM_CONF"; exit 0; fi
  sleep 0.1
done
say "the node did not become idle (state: '${state:-none}'); logs in $dir/log"
tail -5 "$dir"/log/*.log >&2 || true
stop
exit 1
