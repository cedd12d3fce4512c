#!/usr/bin/env bash
# slurm-up.sh - bring up a real one-node Slurm (Debian's Slurm 22.05 + munge) on
# this machine, without systemd, for testing the radiosity engine's
# `--cluster slurm` path with dask-jobqueue.
#
# Idempotent: run it as often as you like. It installs what is missing, starts
# what is not running, restarts the daemons only if the generated slurm.conf
# changed, and waits until the controller answers and the node is usable.
#
# Where things live
#   /etc/slurm/slurm.conf   the config. Debian's Slurm reads this path by
#                           default, so sbatch/squeue/dask-jobqueue work in any
#                           shell without extra environment. An existing file
#                           that this script did not write is backed up first
#                           (slurm.conf.radiosity-backup.<timestamp>).
#                           The script also exports SLURM_CONF=/etc/slurm/slurm.conf
#                           for itself and prints that line for `eval`, which
#                           overrides a stray SLURM_CONF in the caller's shell.
#   $RADIOSITY_SLURM_DIR    (default /tmp/radiosity-slurm) all state, spool,
#                           pid and log files: state/ spool/ run/ log/.
#   /etc/munge/munge.key    munge key (created if missing); munged runs as the
#                           munge user with its default socket/pid in /run/munge.
#
# Environment
#   RADIOSITY_SLURM_DIR       state directory (default /tmp/radiosity-slurm)
#   RADIOSITY_SLURM_TIMEOUT   seconds to wait for readiness (default 60)
#   RADIOSITY_SLURM_PARTITION partition name (default debug)
#   RADIOSITY_SLURMCTLD_PORT / RADIOSITY_SLURMD_PORT  (default 6817 / 6818)
#
# Exit codes
#   0  Slurm is up: `scontrol ping` says UP and the node is idle (or busy).
#   1  something went wrong (message on stderr, see the logs it names).
#   3  cannot possibly work here (not root and Slurm not already up, no
#      apt-get, install impossible, ...). Callers (tests) should skip.
#
# Usage
#   sudo deploy/slurm-up.sh            # then: deploy/slurm-down.sh
#   eval "$(deploy/slurm-up.sh | grep '^export ')"

set -uo pipefail

DIR="${RADIOSITY_SLURM_DIR:-/tmp/radiosity-slurm}"
TIMEOUT="${RADIOSITY_SLURM_TIMEOUT:-60}"
PARTITION="${RADIOSITY_SLURM_PARTITION:-debug}"
CTLD_PORT="${RADIOSITY_SLURMCTLD_PORT:-6817}"
SLURMD_PORT="${RADIOSITY_SLURMD_PORT:-6818}"
CONF=/etc/slurm/slurm.conf
MARKER="# managed-by: radiosity deploy/slurm-up.sh"
MUNGE_KEY=/etc/munge/munge.key
MUNGE_RUN=/run/munge
MUNGE_PID="$MUNGE_RUN/munged.pid"
PACKAGES=(slurmctld slurmd slurm-client munge)

export SLURM_CONF="$CONF"
export PATH="/usr/sbin:/usr/bin:/sbin:/bin:$PATH"

T0=$(date +%s.%N)
elapsed() { awk -v a="$T0" -v b="$(date +%s.%N)" 'BEGIN{printf "%5.1f", b-a}'; }
say()  { printf '[slurm-up %ss] %s\n' "$(elapsed)" "$*"; }
warn() { printf '[slurm-up] WARNING: %s\n' "$*" >&2; }
die()  { printf '[slurm-up] ERROR: %s\n' "$*" >&2; exit 1; }
skip() { printf '[slurm-up] CANNOT RUN HERE (exit 3): %s\n' "$*" >&2; exit 3; }

# pid_alive PIDFILE NAME: true if the pid file names a live process called NAME.
pid_alive() {
    local f=$1 name=$2 pid
    [[ -r $f ]] || return 1
    pid=$(tr -dc '0-9' <"$f")
    [[ -n $pid && -r /proc/$pid/comm ]] || return 1
    [[ $(cat "/proc/$pid/comm" 2>/dev/null) == "$name" ]]
}

have_slurm() { command -v slurmctld >/dev/null && command -v slurmd >/dev/null &&
               command -v sbatch >/dev/null && command -v munged >/dev/null; }

node_state() { sinfo -h -N -n "$NODE" -o %T 2>/dev/null | head -n1; }

# When this run started slurmd, the node state recovered from the state files
# can say idle before the new slurmd has registered; also require a
# SlurmdStartTime no older than that start.
SLURMD_STARTED_AT=0
slurmd_registered() {
    (( SLURMD_STARTED_AT > 0 )) || return 0
    local t
    t=$(scontrol show node "$NODE" 2>/dev/null | grep -oE 'SlurmdStartTime=[^ ]+' | cut -d= -f2)
    [[ -n $t && $t != None ]] || return 1
    (( $(date -d "$t" +%s 2>/dev/null || echo 0) >= SLURMD_STARTED_AT - 1 ))
}

slurm_ready() {
    scontrol ping 2>/dev/null | grep -q 'is UP' || return 1
    slurmd_registered || return 1
    case "$(node_state)" in
        idle|mixed|allocated|completing) return 0 ;;
        *) return 1 ;;
    esac
}

NODE=$(hostname -s 2>/dev/null || hostname)
[[ -n $NODE ]] || skip "cannot determine the host name"

# ---------------------------------------------------------------- non-root
if [[ $(id -u) -ne 0 ]]; then
    if have_slurm && slurm_ready; then
        say "not root, but Slurm is already up on $NODE; nothing to do"
        echo "export SLURM_CONF=$CONF"
        exit 0
    fi
    skip "must be run as root (installs packages, starts munged/slurmctld/slurmd)"
fi

# ---------------------------------------------------------------- install
if ! have_slurm; then
    command -v apt-get >/dev/null || skip "Slurm is not installed and there is no apt-get"
    say "installing ${PACKAGES[*]} (services are kept from starting by policy-rc.d)"
    POLICY=/usr/sbin/policy-rc.d
    POLICY_BAK=""
    if [[ -e $POLICY ]]; then
        POLICY_BAK="$POLICY.radiosity-saved.$$"
        cp -p "$POLICY" "$POLICY_BAK"
    fi
    restore_policy() {
        if [[ -n $POLICY_BAK ]]; then mv -f "$POLICY_BAK" "$POLICY"; else rm -f "$POLICY"; fi
    }
    trap restore_policy EXIT
    printf '#!/bin/sh\n# temporary, written by radiosity deploy/slurm-up.sh\nexit 101\n' >"$POLICY"
    chmod 0755 "$POLICY"
    t_inst=$(date +%s)
    apt_install() {
        DEBIAN_FRONTEND=noninteractive apt-get install -y -q --no-install-recommends \
            -o Dpkg::Options::=--force-confdef -o Dpkg::Options::=--force-confold \
            "${PACKAGES[@]}" >"/tmp/radiosity-slurm-apt.$$.log" 2>&1
    }
    if ! apt_install; then
        say "install failed; running apt-get update and retrying"
        apt-get update -q >>"/tmp/radiosity-slurm-apt.$$.log" 2>&1
        if ! apt_install; then
            tail -n 20 "/tmp/radiosity-slurm-apt.$$.log" >&2
            restore_policy; trap - EXIT
            skip "apt-get install ${PACKAGES[*]} failed (log: /tmp/radiosity-slurm-apt.$$.log)"
        fi
    fi
    restore_policy; trap - EXIT
    rm -f "/tmp/radiosity-slurm-apt.$$.log"
    have_slurm || skip "packages installed but slurmctld/slurmd/sbatch/munged still not found"
    say "installed in $(( $(date +%s) - t_inst )) s"
else
    say "slurm and munge already installed"
fi

# ---------------------------------------------------------------- munge
getent passwd munge >/dev/null || die "the munge package did not create the munge user"
if [[ ! -s $MUNGE_KEY ]]; then
    say "creating munge key $MUNGE_KEY"
    mkdir -p "$(dirname "$MUNGE_KEY")"
    if command -v mungekey >/dev/null; then
        mungekey --create --keyfile="$MUNGE_KEY" --force >/dev/null 2>&1 ||
            dd if=/dev/urandom of="$MUNGE_KEY" bs=1024 count=1 status=none
    else
        dd if=/dev/urandom of="$MUNGE_KEY" bs=1024 count=1 status=none
    fi
fi
chown munge:munge "$MUNGE_KEY" "$(dirname "$MUNGE_KEY")"
chmod 0400 "$MUNGE_KEY"
chmod 0700 "$(dirname "$MUNGE_KEY")"
# Without systemd-tmpfiles nobody creates these.
mkdir -p "$MUNGE_RUN" /var/log/munge /var/lib/munge
chown munge:munge "$MUNGE_RUN" /var/log/munge /var/lib/munge
chmod 0755 "$MUNGE_RUN"

munge_works() { munge -n 2>/dev/null | unmunge >/dev/null 2>&1; }
if munge_works; then
    say "munged already running"
else
    if [[ -e $MUNGE_PID ]] && ! pid_alive "$MUNGE_PID" munged; then rm -f "$MUNGE_PID"; fi
    # A dead munged can leave its socket lock behind.
    rm -f "$MUNGE_RUN/munge.socket.2" "$MUNGE_RUN/munge.socket.2.lock" 2>/dev/null
    say "starting munged as user munge"
    runuser -u munge -- /usr/sbin/munged --pid-file="$MUNGE_PID" ||
        die "munged failed to start (see /var/log/munge/munged.log)"
    for _ in $(seq 50); do munge_works && break; sleep 0.1; done
    munge_works || die "munged started but 'munge -n | unmunge' fails (see /var/log/munge/munged.log)"
fi

# ---------------------------------------------------------------- /etc/hosts
# With NoCtldInAddrAny/NoInAddrAny the daemons bind to the address the host
# name resolves to; it must be exactly 127.0.0.1 or srun fails.
resolved_v4() { getent ahostsv4 "$NODE" 2>/dev/null | awk '{print $1}' | sort -u | tr '\n' ' ' | sed 's/ $//'; }
if [[ $(resolved_v4) != "127.0.0.1" ]]; then
    say "host name $NODE resolves to '$(resolved_v4)'; rewriting /etc/hosts so it is 127.0.0.1"
    mkdir -p "$DIR"
    [[ -e $DIR/hosts.orig ]] || cp /etc/hosts "$DIR/hosts.orig"
    # Remove the name from IPv4 lines that map it elsewhere, then add a
    # loopback line. Rewrite in place (cat >), never sed -i: /etc/hosts can be
    # a bind mount, and replacing the file breaks that.
    new=$(awk -v h="$NODE" -v hf="$(hostname)" '
        /^[[:space:]]*#/ || NF < 2 || $1 !~ /^[0-9]+\.[0-9]+\.[0-9]+\.[0-9]+$/ || $1 == "127.0.0.1" { print; next }
        {
            out = $1; kept = 0
            for (i = 2; i <= NF; i++) {
                if ($i ~ /^#/) { for (j = i; j <= NF; j++) out = out " " $j; break }
                if ($i == h || $i == hf) continue
                out = out " " $i; kept++
            }
            if (kept > 0) print out; else print "# " $0 "   # disabled by radiosity slurm-up.sh"
        }' /etc/hosts)
    if ! grep -Eq "^[[:space:]]*127\.0\.0\.1([[:space:]].*)?[[:space:]]$NODE([[:space:]]|\$)" <<<"$new"; then
        new+=$'\n'"127.0.0.1 $NODE   # added by radiosity slurm-up.sh"
    fi
    printf '%s\n' "$new" >/etc/hosts || die "cannot rewrite /etc/hosts"
    [[ $(resolved_v4) == "127.0.0.1" ]] ||
        die "host name $NODE still resolves to '$(resolved_v4)' after editing /etc/hosts (check /etc/nsswitch.conf)"
fi
say "host name $NODE resolves to 127.0.0.1"

# ---------------------------------------------------------------- slurm.conf
mkdir -p "$DIR"/{state,spool/slurmd,run,log}
chmod 0755 "$DIR"
CPUS=$(nproc)
avail_mb=$(awk '/^MemAvailable:/ {print int($2/1024)}' /proc/meminfo)
[[ -n $avail_mb && $avail_mb -gt 0 ]] || avail_mb=$(free -m | awk '/^Mem:/ {print $7}')
# 80 % of the available memory, rounded down to 512 MB so that small changes
# in free memory do not change the config (and force a restart) on every run.
REALMEM=$(( avail_mb * 8 / 10 / 512 * 512 ))
(( REALMEM >= 512 )) || REALMEM=$(( avail_mb * 8 / 10 ))
(( REALMEM >= 100 )) || die "only ${avail_mb} MB of memory available; not enough for Slurm jobs"
DEFMEM=$(( REALMEM / CPUS ))
(( DEFMEM > 1024 )) && DEFMEM=1024

conf=$(cat <<EOF
$MARKER
# Single-node test cluster on 127.0.0.1 without systemd or cgroups.
# Regenerated by deploy/slurm-up.sh; edits are overwritten.
# radiosity-slurm-dir: $DIR
ClusterName=radiosity
SlurmctldHost=$NODE(127.0.0.1)
SlurmctldPort=$CTLD_PORT
SlurmdPort=$SLURMD_PORT
AuthType=auth/munge
CredType=cred/munge
SlurmUser=root
SlurmdUser=root
# Bind only to the address the host name resolves to (127.0.0.1).
CommunicationParameters=NoCtldInAddrAny,NoInAddrAny
# No cgroups here.
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
SelectType=select/cons_tres
SelectTypeParameters=CR_Core_Memory
# Without a default, a job with no --mem takes the whole node.
DefMemPerCPU=$DEFMEM
SchedulerType=sched/backfill
MpiDefault=none
SwitchType=switch/none
ReturnToService=2
MailProg=/bin/true
InactiveLimit=0
KillWait=5
MinJobAge=30
SlurmctldTimeout=60
SlurmdTimeout=60
# Everything under one directory.
StateSaveLocation=$DIR/state
SlurmdSpoolDir=$DIR/spool/slurmd
SlurmctldPidFile=$DIR/run/slurmctld.pid
SlurmdPidFile=$DIR/run/slurmd.pid
SlurmctldLogFile=$DIR/log/slurmctld.log
SlurmdLogFile=$DIR/log/slurmd.log
SlurmctldDebug=info
SlurmdDebug=info
NodeName=$NODE NodeAddr=127.0.0.1 NodeHostname=$NODE CPUs=$CPUS RealMemory=$REALMEM State=UNKNOWN
PartitionName=$PARTITION Nodes=$NODE Default=YES MaxTime=INFINITE State=UP
EOF
)

mkdir -p "$(dirname "$CONF")"
conf_changed=0
# Pid files named by the config now in place (if we wrote it): daemons started
# from an earlier config, perhaps with another RADIOSITY_SLURM_DIR.
OLD_CTLD_PID=""; OLD_SLURMD_PID=""
if [[ -r $CONF ]] && grep -qxF "$MARKER" "$CONF"; then
    OLD_CTLD_PID=$(awk -F= '$1=="SlurmctldPidFile"{print $2}' "$CONF")
    OLD_SLURMD_PID=$(awk -F= '$1=="SlurmdPidFile"{print $2}' "$CONF")
fi
if [[ -e $CONF ]] && ! grep -qxF "$MARKER" "$CONF"; then
    bak="$CONF.radiosity-backup.$(date +%Y%m%d-%H%M%S)"
    cp -p "$CONF" "$bak"
    say "backed up existing $CONF (not ours) to $bak"
fi
if [[ ! -e $CONF ]] || [[ $(cat "$CONF") != "$conf" ]]; then
    printf '%s\n' "$conf" >"$CONF.tmp.$$" && mv -f "$CONF.tmp.$$" "$CONF"
    chmod 0644 "$CONF"
    conf_changed=1
    say "wrote $CONF (node $NODE: CPUs=$CPUS RealMemory=${REALMEM}M DefMemPerCPU=${DEFMEM}M, dir $DIR)"
else
    say "$CONF unchanged (node $NODE: CPUs=$CPUS RealMemory=${REALMEM}M DefMemPerCPU=${DEFMEM}M, dir $DIR)"
fi

# ---------------------------------------------------------------- daemons
stop_by_pidfile() {  # PIDFILE NAME
    local f=$1 name=$2 pid
    pid_alive "$f" "$name" || { rm -f "$f"; return 0; }
    pid=$(tr -dc '0-9' <"$f")
    kill -TERM "$pid" 2>/dev/null
    for _ in $(seq 100); do [[ -d /proc/$pid ]] || break; sleep 0.1; done
    [[ -d /proc/$pid ]] && kill -KILL "$pid" 2>/dev/null
    rm -f "$f"
}

CTLD_PID="$DIR/run/slurmctld.pid"
SLURMD_PID="$DIR/run/slurmd.pid"
if (( conf_changed )); then
    for pair in "$SLURMD_PID slurmd" "${OLD_SLURMD_PID:-$SLURMD_PID} slurmd" \
                "$CTLD_PID slurmctld" "${OLD_CTLD_PID:-$CTLD_PID} slurmctld"; do
        set -- $pair
        if pid_alive "$1" "$2"; then
            say "config changed: stopping $2 (pid $(cat "$1")) to restart it"
            stop_by_pidfile "$1" "$2"
        fi
    done
fi

if pid_alive "$CTLD_PID" slurmctld; then
    say "slurmctld already running (pid $(cat "$CTLD_PID"))"
else
    rm -f "$CTLD_PID"
    say "starting slurmctld -i"
    slurmctld -i -f "$CONF" || die "slurmctld failed to start (see $DIR/log/slurmctld.log)"
fi
if pid_alive "$SLURMD_PID" slurmd; then
    say "slurmd already running (pid $(cat "$SLURMD_PID"))"
else
    rm -f "$SLURMD_PID"
    SLURMD_STARTED_AT=$(date +%s)
    say "starting slurmd"
    slurmd -f "$CONF" || die "slurmd failed to start (see $DIR/log/slurmd.log)"
fi

# ---------------------------------------------------------------- readiness
say "waiting up to ${TIMEOUT}s for 'scontrol ping' UP and node $NODE idle"
deadline=$(( $(date +%s) + TIMEOUT ))
resumed=0
while :; do
    if slurm_ready; then break; fi
    state=$(node_state)
    # A node left down/drained by an earlier run (ReturnToService covers most
    # cases, but not an explicit drain): resume it once.
    if (( ! resumed )) && [[ $state == down* || $state == drain* ]]; then
        scontrol update NodeName="$NODE" State=RESUME >/dev/null 2>&1 && resumed=1
    fi
    if (( $(date +%s) >= deadline )); then
        echo "---- scontrol ping:" >&2; scontrol ping >&2 2>&1
        echo "---- sinfo:" >&2; sinfo -N -l >&2 2>&1
        echo "---- tail $DIR/log/slurmctld.log:" >&2; tail -n 15 "$DIR/log/slurmctld.log" >&2 2>/dev/null
        echo "---- tail $DIR/log/slurmd.log:" >&2; tail -n 15 "$DIR/log/slurmd.log" >&2 2>/dev/null
        die "Slurm not ready after ${TIMEOUT}s (controller: $(scontrol ping 2>&1 | head -n1); node state: '${state:-unknown}')"
    fi
    pid_alive "$CTLD_PID" slurmctld || die "slurmctld died (see $DIR/log/slurmctld.log)"
    pid_alive "$SLURMD_PID" slurmd || die "slurmd died (see $DIR/log/slurmd.log)"
    sleep 0.5
done
say "Slurm is up: $(scontrol ping | head -n1 | sed 's/^ *//'); node $NODE $(node_state), partition $PARTITION"
echo "export SLURM_CONF=$CONF"
