#!/usr/bin/env bash
# The leak loop (not in CI: about 3 minutes for 100 runs): runs the smoke graph N times (default 100), killing
# something at random in most runs (SIGKILL a stage, SIGKILL the launcher, SIGINT the launcher,
# SIGSTOP a stage that the stall watchdog must find), then checks that nothing accumulated:
# shared-memory files of the runs, imuflow processes, zombies, and the file descriptors of the
# last launcher (a leak inside one launcher run shows there).
#
#   scripts/leak-loop.sh [N]          # needs target/release/imuflow (cargo build --release)
#
# Each run uses its own graph copy and output folder under a scratch directory, and one
# IMUFLOW_SHM_PREFIX for the whole loop so that only this loop's files are counted. A killed
# launcher's files are removed by the next run's start (as in real use); the loop ends with one
# clean run and then counts.
set -uo pipefail
cd "$(dirname "$0")/.."
runs=${1:-100}
exe=target/release/imuflow
[ -x "$exe" ] || { echo "leak-loop: $exe missing: cargo build --release" >&2; exit 2; }
scratch=$(mktemp -d /tmp/imuflow-leak-loop.XXXXXX)
export IMUFLOW_SHM_PREFIX="imleak$$_"
export IMUFLOW_LOG=error
graph="$scratch/smoke.toml"
# The smoke graph live at 60 Hz for 3 s (so the faults land mid-stream), with a short stall
# timeout so a frozen stage ends its run within seconds.
sed -e "s|out/smoke|$scratch/smoke|g" -e 's/frames = 600/frames = 180/' \
    -e 's/^rate_hz = 60/rate_hz = 60\nmode = "live"\nstall_timeout_s = 2/' \
    configs/examples/smoke.toml > "$graph"

stage_pids() { # pids of this loop's stage processes (their environment carries the prefix)
    for p in /proc/[0-9]*; do
        { tr '\0' '\n' < "$p/environ"; } 2>/dev/null | grep -qx "IMUFLOW_SHM_PREFIX=$IMUFLOW_SHM_PREFIX" || continue
        { tr '\0' ' ' < "$p/cmdline"; } 2>/dev/null | grep -q " stage " && echo "${p#/proc/}"
    done
}

declare -A outcomes
for i in $(seq 1 "$runs"); do
    fault=$(( RANDOM % 5 ))   # 0: none, 1: kill -9 a stage, 2: kill -9 the launcher, 3: Ctrl-C, 4: SIGSTOP a stage
    "$exe" run "$graph" --no-progress --quiet > /dev/null 2>"$scratch/stderr" &
    launcher=$!
    if [ "$fault" -ne 0 ]; then
        sleep "$(( RANDOM % 2 )).$(( RANDOM % 9 + 1 ))"
        case $fault in
            1) victim=$(stage_pids | shuf -n 1); [ -n "$victim" ] && kill -9 "$victim" 2>/dev/null ;;
            2) kill -9 "$launcher" 2>/dev/null ;;
            3) kill -INT "$launcher" 2>/dev/null ;;
            4) victim=$(stage_pids | shuf -n 1); [ -n "$victim" ] && kill -STOP "$victim" 2>/dev/null ;;
        esac
    fi
    wait "$launcher" 2>/dev/null; code=$?
    if [ "$fault" -eq 2 ]; then
        # The launcher is gone; its stages see stdin close and stop. Give them a moment.
        for _ in $(seq 1 50); do [ -z "$(stage_pids)" ] && break; sleep 0.1; done
    fi
    outcomes["fault$fault exit$code"]=$(( ${outcomes["fault$fault exit$code"]:-0} + 1 ))
    printf '\rrun %d/%d' "$i" "$runs" >&2
done
echo >&2
# One clean run: it removes what killed launchers left, and must itself leave nothing.
"$exe" run "$graph" --no-progress --quiet > /dev/null 2>&1 &
last=$!
sleep 1
fds=$(ls "/proc/$last/fd" 2>/dev/null | wc -l)
wait "$last"; last_code=$?
sleep 0.5

shm=$(find /dev/shm /tmp/iceoryx2 -name "${IMUFLOW_SHM_PREFIX}*" 2>/dev/null | wc -l)
procs=$(stage_pids | wc -l)
zombies=$(ps -eo stat,cmd | awk '$1 ~ /^Z/ && /imuflow/' | wc -l)
echo "leak-loop: $runs runs with random faults (fault: 0 none, 1 kill -9 a stage, 2 kill -9 the launcher, 3 SIGINT, 4 SIGSTOP a stage):"
for k in "${!outcomes[@]}"; do echo "  $k: ${outcomes[$k]}"; done | sort
echo "leak-loop: last clean run exit $last_code, its launcher held $fds file descriptors one second in"
echo "leak-loop: left behind: $shm shared-memory files, $procs stage processes, $zombies zombies"
rm -rf "$scratch"
[ "$last_code" -eq 0 ] && [ "$shm" -eq 0 ] && [ "$procs" -eq 0 ] && [ "$zombies" -eq 0 ]
