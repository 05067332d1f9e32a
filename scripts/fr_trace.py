#!/usr/bin/env python3
"""When and where frontier-reaching (FR) walks end, from the actor's FR decision trace.

    scripts/fr_trace.py [--task NAME] [--by T] [--list] [--segments] LOG...

Each LOG is the output of an AntMaze run started with `RUST_LOG=info,actor=debug` (serial mode
or an actor's log): every FR decision is a line "FR decision episode=E t=T xy=Some([x, y]) ...
switch=S". Unlike scripts/fr_outcomes.py, which sees one FR episode per metrics line, this
reads every decision, so it also gives *when* navigation ended (the env step of the stuck or
near-frontier switch) and how far the walk had got by step T (`--by`, default 500: how far it
would have got in a 500-step episode).

Per LOG: FR episodes; how navigation ended (stuck, near the frontier, or no switch before the
episode's end, which includes the rare FR mode ended by a new φ: the trace does not show that);
the median env step of the stuck and near-frontier switches; the median distance s along the
maze (scripts/maze_path.py; `--task`, default antmaze-u, names the run's task) where navigation
ended and the furthest s by step T. `--list` also prints each episode's end as (x, y) t<step><S|N|->.

`--segments` also prints how the low level fares on the way: every navigation segment (a
waypoint decision followed by the next decision of the same episode, c env steps later),
binned by its starting φ distance to the waypoint, with the medians of the ratio end/start
distance, how far φ and the torso xy moved (net) and how much of the distance was closed; and
the φ length of a route hop (consecutive route indices seen in one episode), which the
waypoint offset k multiplies. Standard library only.
"""
import math
import re
import statistics
import sys

import maze_path

ANSI = re.compile(r"\x1b\[[0-9;]*m")
DECISION = re.compile(
    r"FR decision episode=(\d+) t=(\d+) xy=Some\(\[([-\d.e]+), ([-\d.e]+)\]\).*?"
    r"switch=(None|Some\((\w+)\))"
)


def matches(path, pattern):
    """The matches of `pattern` in the log's lines, colour codes removed."""
    with open(path, errors="replace") as lines:
        for line in lines:
            found = pattern.search(ANSI.sub("", line))
            if found:
                yield found


def walks(path):
    """{episode: [(t, x, y, switch or None), ...]} up to and including the first switch."""
    episodes = {}
    for found in matches(path, DECISION):
        episode = int(found[1])
        decisions = episodes.setdefault(episode, [])
        if decisions and decisions[-1][3] is not None:
            continue  # count mode after the switch: not navigation
        decisions.append((int(found[2]), float(found[3]), float(found[4]), found[6]))
    return episodes


SEGMENT = re.compile(
    r"FR decision episode=(\d+) t=(\d+) xy=Some\(\[([-\d.e]+), ([-\d.e]+)\]\) "
    r"phi=\[([-\d.e]+), ([-\d.e]+)\] choice=(\w+)(?: \{ k: \d+, index: Some\((\d+)\) \})?"
    r".*?subgoal=\[([-\d.e]+), ([-\d.e]+)\]"
)
BIN = 4.0  # width of the starting-distance bins, φ units
LAST_BIN = 20.0  # everything from here on is one bin


def decisions(path):
    """{(episode, t): (choice, route index or None, xy, φ, subgoal)} of every FR decision."""
    found_all = {}
    for found in matches(path, SEGMENT):
        episode, t, x, y, px, py, choice, index, sx, sy = found.groups()
        found_all[(int(episode), int(t))] = (
            choice,
            None if index is None else int(index),
            (float(x), float(y)),
            (float(px), float(py)),
            (float(sx), float(sy)),
        )
    return found_all


def segments(found_all):
    """(start distance, end/start ratio, φ moved, xy moved, closed) per navigation segment."""
    by_episode = {}
    for (episode, t) in found_all:
        by_episode.setdefault(episode, []).append(t)
    out = []
    for episode, times in by_episode.items():
        times.sort()
        for t, t_next in zip(times, times[1:]):
            choice, _, xy, phi, goal = found_all[(episode, t)]
            _, _, xy_next, phi_next, _ = found_all[(episode, t_next)]
            start = math.dist(phi, goal)
            if choice != "Waypoint" or start == 0.0:
                continue
            end = math.dist(phi_next, goal)
            out.append((start, end / start, math.dist(phi, phi_next), math.dist(xy, xy_next), start - end))
    return out


def route_hops(found_all):
    """φ distance between route nodes at consecutive indices seen in one episode."""
    nodes = {}
    for (episode, _), (choice, index, _, _, goal) in found_all.items():
        if choice == "Waypoint" and index is not None:
            nodes.setdefault(episode, {})[index] = goal
    hops = []
    for per_index in nodes.values():
        hops.extend(
            math.dist(per_index[i], per_index[i + 1]) for i in per_index if i + 1 in per_index
        )
    return hops


def print_segments(path):
    found_all = decisions(path)
    rows = segments(found_all)
    if not rows:
        print("  no navigation segments")
        return
    bins = {}
    for row in rows:
        bins.setdefault(min(BIN * math.floor(row[0] / BIN), LAST_BIN), []).append(row)
    print("  navigation segments by starting φ distance to the waypoint (medians):")
    for lo in sorted(bins):
        group = bins[lo]
        med = [statistics.median(r[i] for r in group) for i in range(1, 5)]
        upper = "" if lo == LAST_BIN else f"{lo + BIN:.0f}"
        print(
            f"    {lo:.0f}-{upper}: n={len(group)} end/start {med[0]:.2f}, φ moved {med[1]:.1f}, "
            f"xy moved {med[2]:.2f} m, closed {med[3]:.1f}"
        )
    hops = sorted(route_hops(found_all))
    if hops:
        print(
            f"  route hops: n={len(hops)}, φ length median {statistics.median(hops):.2f}, "
            f"max {hops[-1]:.2f}"
        )


def median_or_dash(values, fmt="{:.0f}"):
    return fmt.format(statistics.median(values)) if values else "-"


def summarize(path, maze, by, listing, with_segments):
    episodes = walks(path)
    if not episodes:
        print(f"{path}: no FR decisions (was it run with RUST_LOG=info,actor=debug?)")
        return
    ends = [decisions[-1] for decisions in episodes.values()]
    stuck = [t for t, _, _, switch in ends if switch == "Stuck"]
    near = [t for t, _, _, switch in ends if switch == "NearFrontier"]
    running = len(ends) - len(stuck) - len(near)
    end_s = [maze.progress(x, y) for _, x, y, _ in ends]
    furthest = [
        max((maze.progress(x, y) for t, x, y, _ in decisions if t <= by), default=0.0)
        for decisions in episodes.values()
    ]
    n = len(ends)
    print(
        f"{path}: {n} FR episodes | stuck {len(stuck)} ({100 * len(stuck) / n:.0f} %, median "
        f"step {median_or_dash(stuck)}), near frontier {len(near)} (median step "
        f"{median_or_dash(near)}), no switch {running} | s where navigation ended: median "
        f"{statistics.median(end_s):.1f} m, max {max(end_s):.1f} m | furthest s by step {by}: "
        f"median {statistics.median(furthest):.1f} m"
    )
    if listing:
        mark = {"Stuck": "S", "NearFrontier": "N", None: "-"}
        print("  " + " ".join(f"({x:.1f},{y:.1f})t{t}{mark.get(s, '?')}" for t, x, y, s in ends))
    if with_segments:
        print_segments(path)


def main(argv):
    by, listing, with_segments, paths, task = 500, False, False, [], "antmaze-u"
    args = iter(argv)
    for arg in args:
        if arg == "--by":
            by = int(next(args, "500"))
        elif arg == "--task":
            task = next(args, None) or sys.exit("--task needs a task name (asi tasks lists them)")
        elif arg == "--list":
            listing = True
        elif arg == "--segments":
            with_segments = True
        elif arg.startswith("-"):
            sys.exit(__doc__)
        else:
            paths.append(arg)
    if not paths:
        sys.exit(__doc__)
    maze = maze_path.for_task(task)
    for path in paths:
        summarize(path, maze, by, listing, with_segments)


if __name__ == "__main__":
    main(sys.argv[1:])
