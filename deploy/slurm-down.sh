#!/usr/bin/env bash
# slurm-down.sh - stop the one-node test Slurm started by deploy/slurm-up.sh.
#
# 1. scancel every job and wait (with a timeout) until `squeue` and
#    `scontrol listpids` are empty. Stopping slurmd does NOT kill running
#    jobs, so this must come first.
# 2. Stop slurmd, slurmctld and munged by their pid files (TERM, then KILL
#    after 10 s).
#
# Idempotent: fine to run when nothing is running. It never touches daemons it
# cannot identify by a pid file. /etc/slurm/slurm.conf, the munge key and the
# state directory are left in place (a later slurm-up.sh reuses them; delete
# $RADIOSITY_SLURM_DIR yourself to start from scratch).
#
# Environment
#   RADIOSITY_SLURM_DIR      state directory (default /tmp/radiosity-slurm; if
#                            /etc/slurm/slurm.conf was written by slurm-up.sh,
#                            the pid files named there are used)
#   RADIOSITY_SLURM_TIMEOUT  seconds to wait for jobs to go away (default 60)
#   RADIOSITY_KEEP_MUNGE=1   leave munged running
#
# Exit codes: 0 stopped (or nothing ran); 1 something is still running;
#             3 not root while daemons run (cannot stop them).

set -uo pipefail

DIR="${RADIOSITY_SLURM_DIR:-/tmp/radiosity-slurm}"
TIMEOUT="${RADIOSITY_SLURM_TIMEOUT:-60}"
CONF=/etc/slurm/slurm.conf
MARKER="# managed-by: radiosity deploy/slurm-up.sh"
MUNGE_PID=/run/munge/munged.pid
export SLURM_CONF="$CONF"
export PATH="/usr/sbin:/usr/bin:/sbin:/bin:$PATH"

T0=$(date +%s.%N)
elapsed() { awk -v a="$T0" -v b="$(date +%s.%N)" 'BEGIN{printf "%5.1f", b-a}'; }
say()  { printf '[slurm-down %ss] %s\n' "$(elapsed)" "$*"; }
warn() { printf '[slurm-down] WARNING: %s\n' "$*" >&2; }

CTLD_PID="$DIR/run/slurmctld.pid"
SLURMD_PID="$DIR/run/slurmd.pid"
if [[ -r $CONF ]] && grep -qxF "$MARKER" "$CONF"; then
    v=$(awk -F= '$1=="SlurmctldPidFile"{print $2}' "$CONF"); [[ -n $v ]] && CTLD_PID=$v
    v=$(awk -F= '$1=="SlurmdPidFile"{print $2}' "$CONF");    [[ -n $v ]] && SLURMD_PID=$v
fi

pid_of() {  # PIDFILE NAME -> pid if alive and named NAME
    local f=$1 name=$2 pid
    [[ -r $f ]] || return 1
    pid=$(tr -dc '0-9' <"$f")
    [[ -n $pid && $(cat "/proc/$pid/comm" 2>/dev/null) == "$name" ]] || return 1
    echo "$pid"
}

stop_daemon() {  # PIDFILE NAME
    local f=$1 name=$2 pid
    if ! pid=$(pid_of "$f" "$name"); then
        [[ -e $f ]] && rm -f "$f" 2>/dev/null
        say "$name not running"
        return 0
    fi
    say "stopping $name (pid $pid)"
    kill -TERM "$pid" 2>/dev/null
    for _ in $(seq 100); do [[ -d /proc/$pid ]] || break; sleep 0.1; done
    if [[ -d /proc/$pid ]]; then
        warn "$name (pid $pid) ignored SIGTERM for 10 s; sending SIGKILL"
        kill -KILL "$pid" 2>/dev/null
        sleep 0.5
    fi
    rm -f "$f" 2>/dev/null
    [[ ! -d /proc/$pid ]]
}

# listpids prints a header line, then one line per job process.
job_pids() { scontrol listpids 2>/dev/null | awk 'NR>1 && $1 ~ /^[0-9]+$/ {print $1}'; }
queue()    { squeue -h -o '%i' 2>/dev/null; }

if [[ $(id -u) -ne 0 ]]; then
    for pf in "$SLURMD_PID:slurmd" "$CTLD_PID:slurmctld" "$MUNGE_PID:munged"; do
        if pid_of "${pf%%:*}" "${pf##*:}" >/dev/null; then
            printf '[slurm-down] CANNOT RUN HERE (exit 3): %s is running and only root can stop it\n' "${pf##*:}" >&2
            exit 3
        fi
    done
    say "not root, and nothing to stop"
    exit 0
fi

rc=0
ctld_up=0; pid_of "$CTLD_PID" slurmctld >/dev/null && ctld_up=1
slurmd_up=0; pid_of "$SLURMD_PID" slurmd >/dev/null && slurmd_up=1

# ---------------------------------------------------------------- jobs
if (( ctld_up || slurmd_up )); then
    if (( ctld_up )); then
        jobs=$(queue | tr '\n' ' ')
        if [[ -n ${jobs// } ]]; then
            say "cancelling jobs: $jobs"
            # shellcheck disable=SC2086
            scancel $jobs 2>/dev/null
        else
            say "no jobs in the queue"
        fi
    fi
    deadline=$(( $(date +%s) + TIMEOUT ))
    while :; do
        q=""; p=""
        (( ctld_up )) && q=$(queue)
        (( slurmd_up )) && p=$(job_pids)
        [[ -z $q && -z $p ]] && break
        if (( $(date +%s) >= deadline )); then
            warn "after ${TIMEOUT}s still queued: [$(echo $q)] job pids: [$(echo $p)]"
            if [[ -n $p ]]; then
                warn "killing leftover job processes: $(echo $p)"
                # shellcheck disable=SC2086
                kill -KILL $p 2>/dev/null
            fi
            break
        fi
        # shellcheck disable=SC2046,SC2086
        [[ -n $q ]] && scancel $(echo $q) 2>/dev/null
        sleep 0.5
    done
    say "queue and job processes empty"
fi

# ---------------------------------------------------------------- daemons
stop_daemon "$SLURMD_PID" slurmd       || rc=1
stop_daemon "$CTLD_PID"   slurmctld    || rc=1
if [[ ${RADIOSITY_KEEP_MUNGE:-0} == 1 ]]; then
    say "leaving munged running (RADIOSITY_KEEP_MUNGE=1)"
else
    stop_daemon "$MUNGE_PID" munged    || rc=1
fi

# Anything left that the pid files did not cover (e.g. a slurmstepd)?
# (Zombies, state Z, are ignored: where PID 1 does not reap, the daemons'
# first forks linger as <defunct> entries but hold nothing.)
left=$(ps -eo pid=,stat=,comm= | awk '$2 !~ /^Z/ && $3 ~ /^(slurmctld|slurmd|slurmstepd|slurmscriptd)$/ {print $1"("$3")"}' | tr '\n' ' ')
if [[ -n ${left// } ]]; then
    warn "still running (not started from these pid files?): $left"
    rc=1
fi
(( rc == 0 )) && say "Slurm stopped"
exit $rc
