#!/usr/bin/env bash
# A one-node Slurm cluster on this machine for the duration of one command:
#
#   bash pipelines/slurm/local-cluster.sh DIR COMMAND [ARG]...
#
# writes DIR/slurm.conf (one node: this host at 127.0.0.1, its CPUs up to
# $SLURM_LOCAL_CPUS (default 2) and $SLURM_LOCAL_MEMORY_MB (default 2048) of
# memory as consumable resources, a job above its memory request killed;
# partition `local`), starts a private munged,
# slurmctld and slurmd on ports of their own (state, spool, logs and the munge
# socket all in DIR), waits until `sinfo` shows the node idle, runs COMMAND with
# SLURM_CONF=DIR/slurm.conf, and stops the daemons when it ends, fails or is
# interrupted. The status is COMMAND's. Finished jobs are listed by
# `sacct --completion` (job completion records in DIR/jobcomp.txt: no
# accounting database), and by `squeue --states=all` for MinJobAge (600 s).
# Needs root (slurmd runs jobs as their user) and the Debian packages
# slurm-wlm and munge (.ci/install-deps.sh); no systemd: the daemons are
# started directly, so it runs in containers too.
set -euo pipefail
if [ $# -lt 2 ]; then
    echo "usage: $0 DIR COMMAND [ARG]..." >&2
    exit 64
fi
dir=$1
shift
for tool in munged slurmctld slurmd sinfo; do
    command -v "$tool" >/dev/null 2>&1 || {
        echo "error: $tool not found: install slurm-wlm and munge (.ci/install-deps.sh)" >&2
        exit 1
    }
done
if [ "$(id -u)" -ne 0 ]; then
    echo "error: the local Slurm cluster needs root (slurmd starts jobs as their user)" >&2
    exit 1
fi
mkdir -p "$dir"
dir=$(cd "$dir" && pwd)
chmod 700 "$dir"
mkdir -p "$dir/state" "$dir/spool" "$dir/munge"
chmod 700 "$dir/munge"

# Whether process PID runs (exists and is no zombie waiting for its reaper).
running() {
    local state
    state=$(sed -n 's/^.*) \(.\).*/\1/p' "/proc/$1/stat" 2>/dev/null || true)
    [ -n "$state" ] && [ "$state" != Z ]
}

# The daemons started here (their pid files), stopped on any exit, a failed
# start included: SIGTERM, then SIGKILL to those still there after 10 s.
stop() {
    local status=$? pids=() pid_file pid alive
    for pid_file in "$dir/slurmd.pid" "$dir/slurmctld.pid" "$dir/munge/munged.pid"; do
        pid=$(cat "$pid_file" 2>/dev/null || true)
        [ -n "$pid" ] && pids+=("$pid")
    done
    # Jobs still there (COMMAND failed or was interrupted) are cancelled first:
    # their processes belong to slurmstepd, not to the daemons.
    if [ -s "$dir/slurmctld.pid" ] && [ -n "$(squeue -h -o %i 2>/dev/null || true)" ]; then
        scancel --full --user="$(id -un)" 2>/dev/null || true
        for _ in $(seq 50); do
            [ -z "$(squeue -h -o %i 2>/dev/null || true)" ] && break
            sleep 0.1
        done
    fi
    if [ ${#pids[@]} -gt 0 ]; then
        kill "${pids[@]}" 2>/dev/null || true
        for _ in $(seq 100); do
            alive=0
            for pid in "${pids[@]}"; do running "$pid" && alive=1; done
            [ $alive -eq 0 ] && break
            sleep 0.1
        done
        kill -9 "${pids[@]}" 2>/dev/null || true
    fi
    exit $status
}
trap stop EXIT
trap 'exit 130' INT
trap 'exit 143' TERM

# A free TCP port on 127.0.0.1 (none of `ss -ltn`'s), from a random start.
free_port() {
    local used port
    used=$(ss -Htan | awk '{ n = split($4, a, ":"); print a[n] }')
    port=$((20000 + RANDOM % 20000))
    while grep -qx "$port" <<<"$used" || [ "$port" -eq "${1:-0}" ]; do
        port=$((port + 1))
    done
    echo "$port"
}
ctld_port=$(free_port)
slurmd_port=$(free_port "$ctld_port")
host=$(hostname -s)
cpus=$(nproc)
want=${SLURM_LOCAL_CPUS:-2}
[ "$cpus" -gt "$want" ] && cpus=$want
memory_mb=${SLURM_LOCAL_MEMORY_MB:-2048}
node=obstacle-node

cat >"$dir/slurm.conf" <<CONF
# One-node cluster written by pipelines/slurm/local-cluster.sh.
ClusterName=obstacle
SlurmctldHost=$host(127.0.0.1)
SlurmctldPort=$ctld_port
SlurmdPort=$slurmd_port
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
AuthInfo=socket=$dir/munge/munge.socket
CredType=cred/munge
StateSaveLocation=$dir/state
SlurmdSpoolDir=$dir/spool
SlurmctldPidFile=$dir/slurmctld.pid
SlurmdPidFile=$dir/slurmd.pid
SlurmctldLogFile=$dir/slurmctld.log
SlurmdLogFile=$dir/slurmd.log
# No cgroups (containers): processes tracked by their parents, no task binding.
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
# Memory sampled every second; a job above its --mem is killed (no cgroups to confine it).
JobAcctGatherType=jobacct_gather/linux
JobAcctGatherParams=OverMemoryKill
JobAcctGatherFrequency=task=1
SwitchType=switch/none
MpiDefault=none
# CPUs and memory are what jobs ask for and get (--cpus-per-task, --mem).
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_Core_Memory
# No accounting database: sacct --completion reads the completion records.
AccountingStorageType=accounting_storage/none
JobCompType=jobcomp/filetxt
JobCompLoc=$dir/jobcomp.txt
MinJobAge=600
ReturnToService=2
SlurmdParameters=config_overrides
SlurmctldTimeout=30
SlurmdTimeout=30
NodeName=$node NodeHostname=$host NodeAddr=127.0.0.1 CPUs=$cpus RealMemory=$memory_mb State=UNKNOWN
PartitionName=local Nodes=$node Default=YES MaxTime=INFINITE State=UP
CONF
export SLURM_CONF=$dir/slurm.conf

# munged with a key of its own, on a socket of its own.
dd if=/dev/urandom of="$dir/munge/munge.key" bs=1024 count=1 status=none
chmod 400 "$dir/munge/munge.key"
munged --force --socket="$dir/munge/munge.socket" --key-file="$dir/munge/munge.key" \
    --pid-file="$dir/munge/munged.pid" --log-file="$dir/munge/munged.log" \
    --seed-file="$dir/munge/munged.seed"
slurmctld -f "$dir/slurm.conf" -i
slurmd -f "$dir/slurm.conf" -N "$node"

# Up when sinfo shows the node idle (30 s at most).
for i in $(seq 300); do
    state=$(sinfo -h -n "$node" -o '%t' 2>/dev/null || true)
    [ "$state" = idle ] && break
    if [ "$i" -eq 300 ]; then
        echo "error: the local Slurm node is not idle after 30 s (state: ${state:-none}); logs in $dir:" >&2
        tail -n 20 "$dir/slurmctld.log" "$dir/slurmd.log" "$dir/munge/munged.log" >&2 || true
        exit 1
    fi
    sleep 0.1
done
echo "local Slurm cluster up: node $node ($cpus CPUs, $memory_mb MB), partition local, SLURM_CONF=$SLURM_CONF" >&2
"$@"
