#!/usr/bin/env bash
# A real single-node SLURM on this machine (slurmctld + slurmd on localhost, munge authentication), to run the
# workflow through `snakemake --workflow-profile workflow/profiles/slurm` without a cluster (tests/test_slurm.py).
#
#   sudo workflow/scripts/local_slurm.sh          # install if missing, configure, start; prints the node line
#   workflow/scripts/local_slurm.sh --status      # exit 0 when the cluster answers and its node takes jobs
#   sudo workflow/scripts/local_slurm.sh --stop   # stop the three daemons (the configuration stays)
#
# Idempotent: a second call finds the cluster running and changes nothing. Needs root (apt-get, daemons under
# /etc and /var); Debian/Ubuntu's slurm-wlm (22.05 on Debian 12) and munge, installed with apt-get when missing.
# Without systemd (containers) the daemons are started directly; nothing here needs cgroups.
#
# Job records. Debian's 22.05 has no accounting_storage/filetxt (removed from SLURM long ago); a job database
# needs slurmdbd + MySQL/MariaDB, which this does not set up. Instead:
#   * JobCompType=jobcomp/filetxt: one line per finished job (JobId, Name, JobState, WorkDir, times, TRES)
#     appended to JobCompLoc (/var/log/slurm/jobcomp.log), kept across restarts; `sacct -c` reads that file
#     (plain `sacct` answers "Slurm accounting storage is disabled");
#   * MinJobAge=86400: slurmctld keeps finished jobs for a day, so `squeue --states=all` and
#     `scontrol show job <id>` still show them -- with the Comment where the Snakemake executor writes
#     `rule_<name>_wildcards_<values>`. The executor's status queries must use squeue here
#     (`--slurm-status-command squeue`; its default, sacct, fails without accounting).
set -euo pipefail

CONF_DIR=/etc/slurm
CONF=$CONF_DIR/slurm.conf
LOG_DIR=/var/log/slurm
STATE_DIR=/var/lib/slurm
JOBCOMP=$LOG_DIR/jobcomp.log
PARTITION=local
CONF_VERSION="# version 2"   # bumped when the configuration below changes: a running cluster is then restarted

say() { printf 'local_slurm: %s\n' "$*" >&2; }
die() { say "$1"; exit "${2:-1}"; }

node_state() { sinfo -h -N -o '%T' 2>/dev/null | head -n1; }

running() {
    # the controller answers and the node takes jobs (idle, mixed or allocated; not down/drained)
    command -v scontrol >/dev/null 2>&1 || return 1
    scontrol ping 2>/dev/null | grep -q 'is UP' || return 1
    case "$(node_state)" in idle*|mix*|alloc*|completing*) return 0 ;; *) return 1 ;; esac
}

munge_ok() { command -v munge >/dev/null 2>&1 && munge -n 2>/dev/null | unmunge >/dev/null 2>&1; }

stop_slurm() {
    local name pid
    for name in slurmd slurmctld; do
        pid=$(cat "/run/$name.pid" 2>/dev/null || true)
        if [ -n "$pid" ] && kill -0 "$pid" 2>/dev/null; then
            kill "$pid" && say "stopped $name ($pid)"
            for _ in $(seq 50); do kill -0 "$pid" 2>/dev/null || break; sleep 0.1; done
        fi
    done
}

stop() {
    local pid
    stop_slurm
    pid=$(cat /run/munge/munged.pid 2>/dev/null || true)
    if [ -n "$pid" ] && kill -0 "$pid" 2>/dev/null; then kill "$pid" && say "stopped munged ($pid)"; fi
}

case "${1:-}" in
    --status) running; exit $? ;;
    --stop) stop; exit 0 ;;
    "") ;;
    *) die "usage: $0 [--status|--stop]" 2 ;;
esac

if running && [ -f "$CONF" ] && grep -q '^# Written by workflow/scripts/local_slurm.sh' "$CONF" \
        && [ "$(sed -n 2p "$CONF")" = "$CONF_VERSION" ]; then
    say "already running: $(sinfo -h -N -o '%N %T cpus=%c mem=%mMB partition=%P')"
    exit 0
fi
if running && ! grep -q '^# Written by workflow/scripts/local_slurm.sh' "$CONF" 2>/dev/null; then
    # a SLURM that this script did not configure (a real cluster's node, say): use it as it is
    say "already running (not configured here): $(sinfo -h -N -o '%N %T cpus=%c mem=%mMB partition=%P')"
    exit 0
fi
[ "$(id -u)" = 0 ] || die "SLURM is not running and starting it needs root (apt-get, /etc/slurm, daemons)" 3

# 1. packages
if ! command -v slurmctld >/dev/null 2>&1 || ! command -v slurmd >/dev/null 2>&1 || ! command -v munged >/dev/null 2>&1; then
    command -v apt-get >/dev/null 2>&1 || die "slurm-wlm/munge are missing and there is no apt-get to install them" 4
    say "installing slurm-wlm and munge (apt-get)"
    export DEBIAN_FRONTEND=noninteractive
    apt-get install -y -q slurm-wlm munge >/dev/null 2>&1 \
        || { apt-get update -q >/dev/null 2>&1 && apt-get install -y -q slurm-wlm munge >/dev/null; } \
        || die "apt-get install slurm-wlm munge failed (no network or no package source?)" 4
fi

# 2. munge: a key (the package makes one; made here when absent) and the daemon
if [ ! -s /etc/munge/munge.key ]; then
    install -d -o munge -g munge -m 0700 /etc/munge
    if command -v mungekey >/dev/null 2>&1; then mungekey --create --force
    else dd if=/dev/urandom of=/etc/munge/munge.key bs=1 count=1024 2>/dev/null; fi
    chown munge:munge /etc/munge/munge.key && chmod 0400 /etc/munge/munge.key
fi
install -d -o munge -g munge -m 0755 /run/munge
install -d -o munge -g munge -m 0700 /var/lib/munge /var/log/munge
if ! munge_ok; then
    say "starting munged"
    runuser -u munge -- /usr/sbin/munged
    for _ in $(seq 50); do munge_ok && break; sleep 0.1; done
    munge_ok || die "munged does not answer (see /var/log/munge/munged.log)" 5
fi

# 3. configuration: this node's real CPUs and memory (slurmd -C), one partition, no cgroups, no database
host=$(hostname -s)
node_line=$(slurmd -C | head -n1)          # NodeName=<host> CPUs=.. Boards=.. ... RealMemory=..
case "$node_line" in NodeName=*) ;; *) die "slurmd -C gave no node line: $node_line" 5 ;; esac
install -d -m 0755 "$CONF_DIR"
install -d -o slurm -g slurm -m 0755 "$LOG_DIR" "$STATE_DIR" "$STATE_DIR/slurmctld" "$STATE_DIR/slurmd"
gres_types="" node_gres=""
if command -v nvidia-smi >/dev/null 2>&1 && ngpu=$(nvidia-smi -L 2>/dev/null | grep -c '^GPU') && [ "$ngpu" -gt 0 ]; then
    # GPUs: --gpus=N / --gres=gpu:N requests (METRAW_SLURM_GPUS with the SLURM profile) are granted on this node
    gres_types="GresTypes=gpu" node_gres="Gres=gpu:$ngpu"
    printf 'Name=gpu File=/dev/nvidia[0-%d]\n' "$((ngpu - 1))" > "$CONF_DIR/gres.conf"
fi
new_conf=$(cat <<EOF
# Written by workflow/scripts/local_slurm.sh: single-node SLURM on localhost, for the workflow's SLURM profile.
$CONF_VERSION
ClusterName=metraw-local
SlurmctldHost=$host
SlurmUser=slurm
SlurmdUser=root
AuthType=auth/munge
StateSaveLocation=$STATE_DIR/slurmctld
SlurmdSpoolDir=$STATE_DIR/slurmd
SlurmctldPidFile=/run/slurmctld.pid
SlurmdPidFile=/run/slurmd.pid
SlurmctldLogFile=$LOG_DIR/slurmctld.log
SlurmdLogFile=$LOG_DIR/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/linux
MpiDefault=none
SchedulerType=sched/backfill
# jobs run at the OS priority (nice value) of the sbatch that submitted them: a niced snakemake nices its jobs
PropagatePrioProcess=1
SelectType=select/cons_tres
SelectTypeParameters=CR_Core_Memory
DefMemPerCPU=1000
ReturnToService=2
MinJobAge=86400
AccountingStorageType=accounting_storage/none
JobCompType=jobcomp/filetxt
JobCompLoc=$JOBCOMP
$gres_types
$node_line $node_gres State=UNKNOWN
PartitionName=$PARTITION Nodes=$host Default=YES MaxTime=INFINITE State=UP
EOF
)
if [ ! -f "$CONF" ] || [ "$(cat "$CONF")" != "$new_conf" ]; then
    running && { say "configuration changed: restarting slurmctld and slurmd"; stop_slurm; }
    printf '%s\n' "$new_conf" > "$CONF"
    say "wrote $CONF"
fi
touch "$JOBCOMP" && chown slurm:slurm "$JOBCOMP"

# 4. daemons (a half-started cluster, e.g. after a reboot of the container, is restarted)
if ! scontrol ping 2>/dev/null | grep -q 'is UP'; then
    pid=$(cat /run/slurmctld.pid 2>/dev/null || true)   # a controller that does not answer: replace it
    if [ -n "$pid" ] && kill "$pid" 2>/dev/null; then sleep 1; fi
    slurmctld || die "slurmctld did not start (see $LOG_DIR/slurmctld.log)" 5
fi
pid=$(cat /run/slurmd.pid 2>/dev/null || true)
if [ -z "$pid" ] || ! kill -0 "$pid" 2>/dev/null; then
    slurmd || die "slurmd did not start (see $LOG_DIR/slurmd.log)" 5
fi
for _ in $(seq 100); do running && break; sleep 0.2
    case "$(node_state)" in down*|drain*) scontrol update nodename="$host" state=resume 2>/dev/null || true ;; esac
done
running || die "the node does not take jobs: $(sinfo -h -N -o '%N %T %E' 2>&1) (see $LOG_DIR/slurmd.log)" 5
say "started: $(sinfo -h -N -o '%N %T cpus=%c mem=%mMB partition=%P'); job records: $JOBCOMP"
