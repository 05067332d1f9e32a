#!/usr/bin/env python3
"""How far the frontier-reaching (FR) episodes of maze runs got, by stretch of training.

    scripts/fr_outcomes.py [--stretches A-B,C-D,...] [--gain] [--far-goals] RUN_DIR...

Reads each run's metrics.jsonl (standard library only) and takes one record per finished FR
episode of actor 0 from the `actor0/actor/fr/last_*` values (docs/METRICS.md): how its
navigation ended (near the frontier, stuck, new phi, or still navigating when the episode
ended) and where (`last_x`, `last_y`). Those values are of the last FR episode before each
metrics line, so an FR episode that finished between two lines with another is missed; runs
whose lines carry the outcome counters (`actor/fr/near_frontier_switches`,
`stuck_while_navigating`, `new_phi_while_navigating`, `navigating_at_end`; builds from 1118c0e
on) also get the exact count of each outcome per stretch from them. Positions are measured
along the maze from the start, s in metres (scripts/maze_path.py, on the maze of the run's task: in AntMaze-U the centreline
(0, 0) -> (8, 0) -> (8, 8) -> (0, 8), the test goal at s = 24). Runs of builds before these
metrics existed print no FR episodes.

Prints, per run and stretch of training episodes: the FR episodes, the share of each outcome,
the median s where they ended (all of them, and those still navigating at the episode's end)
and the largest s. Stretches default to 201-500, 501-1000, 1001-1500, 1501-2000 (the
reference schedule with 500-step episodes); `--stretches 101-250,251-500,...` for
configs/antmaze-u-1000.toml, whose episodes are twice as long. Runs whose lines carry `actor0/actor/last_episode_x/y` (builds from
f2f9192 on) also get where every episode ended, ordinary and FR episodes apart (an episode is
FR when `actor/fr/last_episode` equals `actor/episodes` on its line). docs/RESULTS.md ("How far
an FR episode gets") was made with it.

`--gain` also prints, per stretch, the mean coverage each episode added
(`learner/charts/coverage` minus the previous line's, for lines one actor-0 episode apart),
FR episodes (those where `actor/fr/episodes` grew) and ordinary ones apart, and their ratio:
how much an FR episode is worth in exploration. Serial runs (one actor) only.

`--far-goals` also prints, per stretch, the far-goal training successes the count schedule
counted (SPEC §6.4; they set `count_prob`), FR episodes and ordinary ones apart: an episode's
success is the rise of `learner/schedule/window_far_goal_successes` over the previous line's;
on the line where a window closed (the counter starts again) it is the closed window's total,
recovered from the new `count_prob` = 1/(1 + exp(2x − 1)) as x · `count_prob_success_unit`
(read from the run's config.resolved.toml), minus what the window had counted before. With
`asi.fr_in_count_window = false` FR episodes are not counted, so their figure is 0. Serial
runs (one actor) only.
"""
import json
import math
import re
import statistics
import sys

import maze_path
from run_archive import open_text

PREFIX = "actor0/actor/fr/"
OUTCOMES = {0: "near frontier", 1: "stuck", 2: "new phi", 3: "still navigating"}
# The counter of each outcome (builds from 1118c0e on): every finished FR episode counts one.
OUTCOME_COUNTERS = {
    0: "near_frontier_switches",
    1: "stuck_while_navigating",
    2: "new_phi_while_navigating",
    3: "navigating_at_end",
}
COVERAGE = "learner/charts/coverage"
STRETCHES = [(201, 500), (501, 1000), (1001, 1500), (1501, 2000)]


def records(path):
    """The JSON objects of metrics.jsonl (or of its packed form, scripts/run_archive.py),
    skipping a line cut by a kill."""
    with open_text(path) as lines:
        for line in lines:
            try:
                yield json.loads(line)
            except ValueError:
                continue


def fr_episodes(path, maze):
    """(training episode, outcome, s) of every FR episode recorded in metrics.jsonl; s along
    `maze` (a maze_path.MazePath)."""
    seen = {}
    for record in records(path):
        if record.get(PREFIX + "last_outcome") is None:
            continue
        key = int(record[PREFIX + "last_episode"])
        if key not in seen:
            seen[key] = (
                int(record["learner/schedule/train_episodes"]),
                int(record[PREFIX + "last_outcome"]),
                maze.progress(record[PREFIX + "last_x"], record[PREFIX + "last_y"]),
            )
    return list(seen.values())


def episode_ends(path, maze):
    """(training episode, was FR, s) of every episode whose end position is recorded."""
    seen = {}
    for record in records(path):
        if record.get("actor0/actor/last_episode_x") is None:
            continue
        key = int(record["actor0/actor/episodes"])
        if key not in seen:
            fr = record.get(PREFIX + "last_episode") == record["actor0/actor/episodes"]
            seen[key] = (
                int(record["learner/schedule/train_episodes"]),
                fr,
                maze.progress(record["actor0/actor/last_episode_x"], record["actor0/actor/last_episode_y"]),
            )
    return list(seen.values())


def outcome_counts(path, stretches):
    """{(lo, hi): [count of each outcome code]} from actor 0's outcome counters: each counter's
    rise from the last line before training episode `lo` to the last line at or before `hi`.
    Exact, where `fr_episodes` sees only the last FR episode of each metrics line. {} for runs
    whose lines lack the counters (builds before 1118c0e)."""
    keys = [PREFIX + OUTCOME_COUNTERS[code] for code in sorted(OUTCOME_COUNTERS)]
    lines = []
    for record in records(path):
        if record.get(keys[1]) is None or record.get("learner/schedule/train_episodes") is None:
            continue
        lines.append((record["learner/schedule/train_episodes"], [record.get(k, 0) for k in keys]))
    if not lines:
        return {}

    def at(episode):
        """The counters of the last line at or before `episode` (zeros before the first)."""
        found = [0] * len(keys)
        for train, counts in lines:
            if train > episode:
                break
            found = counts
        return found

    return {
        (lo, hi): [int(b - a) for a, b in zip(at(lo - 1), at(hi))]
        for lo, hi in stretches
        if lines[0][0] <= hi and lo <= lines[-1][0]
    }


def coverage_gains(path):
    """(training episode, was FR, coverage added) for each metrics line one episode after the last."""
    gains, previous = [], None
    for record in records(path):
        if record.get(COVERAGE) is None or record.get("actor0/actor/episodes") is None:
            continue
        if previous is not None and record["actor0/actor/episodes"] == previous["actor0/actor/episodes"] + 1:
            fr = record.get(PREFIX + "episodes", 0) > previous.get(PREFIX + "episodes", 0)
            gains.append((
                int(record["learner/schedule/train_episodes"]),
                fr,
                record[COVERAGE] - previous[COVERAGE],
            ))
        previous = record
    return gains


def config_value(run, key, default):
    """A number `key = value` of the run's config.resolved.toml (`default` when absent)."""
    try:
        with open(f"{run}/config.resolved.toml") as text:
            found = re.search(rf"^{key}\s*=\s*([0-9.eE+-]+)\s*$", text.read(), re.MULTILINE)
    except OSError:
        return default
    return float(found.group(1)) if found else default


def far_goal_successes(path, unit):
    """(training episode, was FR, far-goal successes counted: 0 or 1) for each metrics line one
    training episode after the last. `unit` is the run's `count_prob_success_unit`."""
    train, window = "learner/schedule/train_episodes", "learner/schedule/window_far_goal_successes"
    length = "learner/schedule/window_episodes"
    out, previous = [], None
    for record in records(path):
        if record.get(window) is None or record.get(train) is None:
            continue
        if previous is not None and record[train] == previous[train] + 1:
            fr = record.get(PREFIX + "episodes", 0) > previous.get(PREFIX + "episodes", 0)
            if record.get(length, 0) < previous.get(length, 0):
                # The window closed with this episode: its total from the new count_prob.
                p = record["learner/schedule/count_prob"]
                total = round(unit * (math.log(1.0 / p - 1.0) + 1.0) / 2.0)
                got = total - previous[window]
            else:
                got = record[window] - previous[window]
            out.append((int(record[train]), fr, int(got)))
        previous = record
    return out


def mean_gain(values):
    return f"{1e3 * sum(values) / len(values):.2f}e-3 (n={len(values)})" if values else "-"


def median_or_dash(values):
    return f"{statistics.median(values):.1f} m (n={len(values)})" if values else "-"


def parse_stretches(text):
    """`A-B,C-D` -> [(A, B), (C, D)]; SystemExit with a message on anything else."""
    stretches = []
    for part in text.split(","):
        try:
            lo, hi = (int(v) for v in part.split("-"))
        except ValueError:
            sys.exit(f"--stretches: '{part}' is not FIRST-LAST (e.g. 101-250)")
        if lo > hi:
            sys.exit(f"--stretches: '{part}' ends before it starts")
        stretches.append((lo, hi))
    return stretches


def options(args, switches, stretches, usage, values=None):
    """(stretches, the options given, run folders) of `[--stretches A-B,...] [SWITCH...]
    [OPTION VALUE...] RUN_DIR...`. `values` maps a value option to (default, convert); the
    options given is a dict holding every value option (its default unless given) and the
    switches given (True). SystemExit with `usage` on an unknown option, with a message on a
    missing or invalid value, and with `usage` and status 2 without a run."""
    values = values or {}
    given = {name: default for name, (default, _) in values.items()}
    run_dirs = []
    rest = iter(args)
    for arg in rest:
        if arg == "--stretches" or arg in values:
            value = next(rest, None)
            if value is None:
                sys.exit(f"{arg} needs a value")
            if arg == "--stretches":
                stretches = parse_stretches(value)
                continue
            try:
                given[arg] = values[arg][1](value)
            except ValueError as err:
                sys.exit(f"{arg} {value}: {err}")
        elif arg in switches:
            given[arg] = True
        elif arg.startswith("-"):
            sys.exit(f"unknown option {arg}\n{usage}")
        else:
            run_dirs.append(arg)
    if not run_dirs:
        print(usage, file=sys.stderr)
        sys.exit(2)
    return stretches, given, run_dirs


def main(args):
    stretches, given, run_dirs = options(args, {"--gain", "--far-goals"}, STRETCHES, __doc__)
    gain = "--gain" in given
    for run in run_dirs:
        maze = maze_path.for_run(run)
        episodes = fr_episodes(f"{run}/metrics.jsonl", maze)
        print(f"== {run}: {len(episodes)} FR episodes with an outcome")
        for lo, hi in stretches:
            stretch = [e for e in episodes if lo <= e[0] <= hi]
            if not stretch:
                continue
            shares = " ".join(
                f"{name} {sum(e[1] == code for e in stretch) / len(stretch):.0%}"
                for code, name in OUTCOMES.items()
            )
            navigating = [e[2] for e in stretch if e[1] == 3]
            nav_median = f"{statistics.median(navigating):.1f}" if navigating else "-"
            print(
                f"  {lo}-{hi}: n={len(stretch)} | {shares} | s median {statistics.median(e[2] for e in stretch):.1f} m"
                f" (still navigating: {nav_median} m), max {max(e[2] for e in stretch):.1f} m"
            )
        counted = outcome_counts(f"{run}/metrics.jsonl", stretches)
        if counted:
            print("  outcomes counted (all finished FR episodes of actor 0):")
        for (lo, hi), counts in counted.items():
            total = sum(counts)
            shares = " ".join(
                f"{OUTCOMES[code]} {counts[code] / total:.0%}" if total else f"{OUTCOMES[code]} -"
                for code in OUTCOMES
            )
            print(f"  {lo}-{hi}: n={total} | {shares}")
        ends = episode_ends(f"{run}/metrics.jsonl", maze)
        if ends:
            print(f"  where episodes ended ({len(ends)} recorded), median s:")
        for lo, hi in stretches:
            stretch = [e for e in ends if lo <= e[0] <= hi]
            if stretch:
                ordinary = [e[2] for e in stretch if not e[1]]
                fr = [e[2] for e in stretch if e[1]]
                print(f"  {lo}-{hi}: ordinary {median_or_dash(ordinary)}, FR {median_or_dash(fr)}")
        if gain:
            print_gains(coverage_gains(f"{run}/metrics.jsonl"), stretches)
        if "--far-goals" in given:
            unit = config_value(run, "count_prob_success_unit", 5.0)
            print_far_goals(far_goal_successes(f"{run}/metrics.jsonl", unit), stretches)
    return 0


def print_far_goals(successes, stretches):
    """Far-goal successes of FR and of ordinary episodes in each stretch."""
    print("  far-goal training successes (counted by the count schedule):")
    for lo, hi in stretches:
        fr = [n for e, is_fr, n in successes if lo <= e <= hi and is_fr]
        ordinary = [n for e, is_fr, n in successes if lo <= e <= hi and not is_fr]
        if fr or ordinary:
            print(f"  {lo}-{hi}: FR {sum(fr)} of {len(fr)} episodes, ordinary {sum(ordinary)} of {len(ordinary)}")


def print_gains(gains, stretches):
    """Mean coverage added per FR and per ordinary episode in each stretch, and the ratio."""
    print("  coverage added per episode:")
    for lo, hi in stretches:
        fr = [g for e, is_fr, g in gains if lo <= e <= hi and is_fr]
        ordinary = [g for e, is_fr, g in gains if lo <= e <= hi and not is_fr]
        if not fr and not ordinary:
            continue
        ratio = "-"
        if fr and ordinary and sum(ordinary) > 0:
            ratio = f"{(sum(fr) / len(fr)) / (sum(ordinary) / len(ordinary)):.1f}"
        print(f"  {lo}-{hi}: FR {mean_gain(fr)}, ordinary {mean_gain(ordinary)}, FR/ordinary {ratio}")


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
