#!/usr/bin/env bash
# The paper's four arms for one seed, forked from shared prefixes (issue #6, claims 1 and 2).
#
#   scripts/paper_arms.sh CONFIG SEED EPISODES OUT_DIR
#
# Arms (serial mode, deterministic for the seed), each in OUT_DIR/<arm>_s<SEED>:
#   asi        FR and SI on (the defaults)
#   asi-no-fr  --set asi.frontier_reaching=false
#   asi-no-si  --set asi.self_imitation=false
#   hess       both off
#   asi-null   ASI with SI's weight asi.si_alpha times 1.01 (the config's, 0.01 where it sets
#              none), forked from asi at SI_START (α acts on nothing before SI starts): a
#              null fork, from which no effect is expected. How far it ends from asi is how
#              far one seed's run can move by chance, the yardstick for the gaps between the
#              arms (docs/RESULTS.md, null forks). Not in the default ARMS.
# FR cannot change anything before asi.fr_start_episode (the actor draws nothing for FR while
# its probability is 0) and SI nothing before asi.si_start_episode, and a serial run stopped
# at an episode count resumes bit-exactly, also with other switches (tests/serial_resume.rs,
# the fork test). So instead of four runs from scratch this runs one trunk to FR_START, copies
# it into an FR-on and an FR-off branch, runs both to SI_START, and copies each into an SI-on
# and an SI-off arm: 4N - FR_START - 2*SI_START episodes instead of 4N, the same results.
# The shared prefixes run with SI on, so the SI buffer holds every episode whichever build runs
# them (before commit 35c4e55 the learner filled it only with SI on, and an SI arm forked from
# an SI-off prefix started with a buffer missing the prefix's episodes).
#
# Environment: ARMS (default "asi asi-no-fr asi-no-si hess": the arms run to EPISODES; e.g.
# ARMS="asi hess" leaves the ablations at their fork points), ASI_BIN (default
# target/release/asi, built if missing), FR_START and SI_START (default: the config's
# asi.fr_start_episode / asi.si_start_episode, 200 and 300 where it sets none; set by hand
# they must equal them, or the script stops before running anything), JOBS (2)
# arms run at once, NICE (19) their priority, CKPT_MINS (10) minutes between checkpoints
# (run.checkpoint_interval_mins; they do not change the results). A stage stopped short of its
# episode count (a signal: asi writes a checkpoint and exits) stops the script with a message,
# after the stages running beside it end. Re-running resumes every
# unfinished stage; a stage killed before its first checkpoint starts over (`--restart`: its
# folder is moved aside to <dir>.old-<secs>, nothing is deleted). The asi and asi-no-fr arms
# go on in their branch's folder, so an arm forked from a branch (asi-no-si and asi-null from
# asi, hess from asi-no-fr) must be asked for before that branch runs on: once it has, the
# script stops with a message instead of copying the wrong episode.
# Curves: asi plot OUT_DIR/asi_s* OUT_DIR/hess_s* ... (the _sN suffix is the seed tag).
set -euo pipefail

if [[ $# -ne 4 ]]; then
    sed -n '2,/^set -e/{/^#/p}' "$0" >&2
    exit 2
fi
config=$1 seed=$2 episodes=$3 out=$4
if [[ ! -f $config ]]; then
    echo "no config file '$config'" >&2
    exit 2
fi
# config_value KEY DEFAULT KIND [SCALE]: the value the config gives KEY (these keys exist only in
# [asi]), or DEFAULT (the binary's default) where it sets none. KIND is int or float; a float is
# printed times SCALE (1 if not given). A value that is not of its kind stops the script with a
# message naming the config, before anything runs.
config_value() {
    python3 - "$config" "$@" <<'EOF'
import re
import sys
path, key, default, kind = sys.argv[1:5]
scale = float(sys.argv[5]) if len(sys.argv) > 5 else 1.0
found = re.search(rf"^\s*{key}\s*=\s*([^#\s]+)\s*(#.*)?$", open(path).read(), re.MULTILINE)
raw = found.group(1) if found else default
try:
    value = int(raw) if kind == "int" else float(raw)
except ValueError:
    sys.exit(f"{path}: {key} = {raw} is not {'an integer' if kind == 'int' else 'a number'}")
print(value if kind == "int" else repr(round(value * scale, 12)))
EOF
}
config_fr=$(config_value fr_start_episode 200 int) || exit 2
config_si=$(config_value si_start_episode 300 int) || exit 2
fr_start=${FR_START:-$config_fr}
si_start=${SI_START:-$config_si}
if (( fr_start != config_fr || si_start != config_si )); then
    echo "FR_START=$fr_start SI_START=$si_start, but $config has asi.fr_start_episode =" \
        "$config_fr and asi.si_start_episode = $config_si: the forks must sit where FR and" \
        "SI start (leave FR_START and SI_START unset to take the config's)" >&2
    exit 2
fi
jobs=${JOBS:-2}
nice_level=${NICE:-19}
ckpt_mins=${CKPT_MINS:-10}
bin=${ASI_BIN:-target/release/asi}
read -r -a arms <<<"${ARMS:-asi asi-no-fr asi-no-si hess}"

if (( episodes <= si_start || si_start <= fr_start )); then
    echo "need FR_START ($fr_start) < SI_START ($si_start) < EPISODES ($episodes)" >&2
    exit 2
fi
for arm in "${arms[@]}"; do
    case $arm in
        asi | asi-no-fr | asi-no-si | hess | asi-null) ;;
        *) echo "unknown arm '$arm' in ARMS (asi, asi-no-fr, asi-no-si, hess, asi-null)" >&2
           exit 2 ;;
    esac
done
# The null fork's α: the config's asi.si_alpha (the binary's 0.01 where it sets none) times 1.01,
# read (and checked) before anything runs.
null_flags=""
if [[ " ${arms[*]} " == *" asi-null "* ]]; then
    alpha=$(config_value si_alpha 0.01 float 1.01) || exit 2
    null_flags="--set asi.si_alpha=$alpha"
fi
if [[ ! -x $bin ]]; then
    cargo build --release
fi
mkdir -p "$out"

# Switches of each arm; the trunk and the FR-off branch run with those of asi-no-fr.
declare -A flags=(
    [asi]=""
    [asi-no-fr]="--set asi.frontier_reaching=false"
    [asi-no-si]="--set asi.self_imitation=false"
    [hess]="--set asi.frontier_reaching=false --set asi.self_imitation=false"
    [asi-null]=$null_flags
)

# Episodes finished by the run in $1 (0 when it has not started).
done_episodes() {
    [[ -d $1/checkpoints/serial ]] || { echo 0; return; }
    python3 - "$1/metrics.jsonl" <<'EOF'
import json, sys
last = 0
try:
    for line in open(sys.argv[1]):
        try:
            last = json.loads(line).get("learner/schedule/train_episodes", last)
        except ValueError:
            pass
except OSError:
    pass
print(int(last))
EOF
}

# run DIR ARM UNTIL: trains the run in DIR with ARM's switches to UNTIL episodes (resuming it;
# nothing to do when it is there already).
run() {
    local dir=$1 arm=$2 until=$3
    if (( $(done_episodes "$dir") >= until )); then
        echo "$(basename "$dir"): at episode $until already"
        return
    fi
    # A folder without a serial checkpoint holds a stage killed before its first one: asi
    # refuses to start over in it, so it is moved aside.
    local restart=""
    if [[ -e $dir && ! -d $dir/checkpoints/serial ]]; then
        restart="--restart"
        echo "$(basename "$dir"): no checkpoint (killed before its first), starting over"
    fi
    echo "$(date -u +%T) $(basename "$dir"): to episode $until (${flags[$arm]:-defaults})"
    # shellcheck disable=SC2086  # the switches are separate words on purpose
    nice -n "$nice_level" "$bin" train --serial --config "$config" --seed "$seed" \
        --run-dir "$dir" $restart ${flags[$arm]} --set run.max_episodes="$until" \
        --set run.checkpoint_interval_mins="$ckpt_mins" >>"$dir.log" 2>&1
    # A run stopped by a signal writes its checkpoint and exits 0 short of UNTIL: the stages
    # after it must not start (a fork would copy the wrong episode).
    local reached
    reached=$(done_episodes "$dir")
    if (( reached < until )); then
        echo "$(date -u +%T) $(basename "$dir"): stopped at episode $reached of $until" \
            "(see $dir.log); run the same command again to resume it" >&2
        return 1
    fi
    echo "$(date -u +%T) $(basename "$dir"): done"
}

# wait_all PID...: waits for every job and fails when any of them failed.
wait_all() {
    local failed=0 pid
    for pid in "$@"; do
        wait "$pid" || failed=1
    done
    return "$failed"
}

# fork FROM TO AT: copies the prefix in FROM, which must be at episode AT, unless TO exists
# already (then it is resumed). The asi and asi-no-fr arms go on in their branch's folder, so a
# branch that has run on as an arm is past its fork point and cannot be forked any more (a
# copy of it would be that arm, not the new one).
fork() {
    if [[ ! -e $2 ]]; then
        local at
        at=$(done_episodes "$1")
        if (( at != $3 )); then
            echo "cannot fork $(basename "$2") from $(basename "$1"): that run is at episode" \
                "$at, not at the fork point $3 (it went on as an arm); run every arm of a seed" \
                "in one call, or fork by hand from a copy kept at episode $3" >&2
            exit 1
        fi
        cp -a "$1" "$2"
        cp "$1.log" "$2.log"
    fi
}

trunk=$out/trunk_s$seed fr_on=$out/asi_s$seed fr_off=$out/asi-no-fr_s$seed
run "$trunk" asi-no-fr "$fr_start"

fork "$trunk" "$fr_on" "$fr_start"
fork "$trunk" "$fr_off" "$fr_start"
# Both branches to SI_START.
run "$fr_on" asi "$si_start" &
on=$!
run "$fr_off" asi-no-fr "$si_start" &
wait_all "$on" $!

if [[ " ${arms[*]} " == *" asi-no-si "* ]]; then fork "$fr_on" "$out/asi-no-si_s$seed" "$si_start"; fi
if [[ " ${arms[*]} " == *" asi-null "* ]]; then fork "$fr_on" "$out/asi-null_s$seed" "$si_start"; fi
if [[ " ${arms[*]} " == *" hess "* ]]; then fork "$fr_off" "$out/hess_s$seed" "$si_start"; fi
# The arms to EPISODES, JOBS at a time.
pids=()
for arm in "${arms[@]}"; do
    while (( $(jobs -rp | wc -l) >= jobs )); do wait -n || true; done
    run "$out/${arm}_s$seed" "$arm" "$episodes" &
    pids+=($!)
done
wait_all "${pids[@]}"
echo "$(date -u +%T) seed $seed: ${arms[*]} at $episodes episodes in $out"
