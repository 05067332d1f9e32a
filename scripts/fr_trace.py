#!/usr/bin/env python3
"""When and where frontier-reaching (FR) walks end, from the actor's FR decision trace.

    scripts/fr_trace.py [--task NAME] [--by T] [--list] [--segments] [--frontiers [--window N]] LOG...

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
waypoint offset k multiplies.

`--frontiers` asks where the near-frontier switches fired relative to the frontier, in the
maze: whether a walk stopped across a wall from its frontier (the switch is a Euclidean test in
φ, within `asi.frontier_epsilon`, so it can fire through a wall where a corridor folds back).
The trace gives the frontier in φ only ("FR episode assigned ... frontier=[..]", the line
before the episode's first decision); its place in the maze is estimated as the xy of the
decision state, of any FR episode within ±N episodes (`--window`, default 5; φ is fixed
between two φ rounds, every 100 episodes by default, so a window inside one such stretch
locates more without mixing maps), whose φ is nearest to it, and counts as
located when that φ is within 4 φ units (φ drifts between rounds, so a frontier no walk came
near is left out). A switch counts as through a wall when the straight line from it to the
frontier is at least one maze cell shorter than the way along the maze (the difference of
their s): around one corner it cuts less than that unless both ends lie more than 1.7
cells from the corner. The same is asked of the stuck walks and their last waypoint (the
route node k past the nearest one, located the same way): a route that folds back puts it
across the wall. Standard library only.
"""
import functools
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


@functools.lru_cache(maxsize=4)  # --frontiers reads each log through both; callers only read
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
    r"phi=\[([-\d.e]+), ([-\d.e]+)\] choice=(\w+)(?: \{ k: \d+, index: Some\((\d+)\)(?:, cut: \w+)? \})?"
    r".*?subgoal=\[([-\d.e]+), ([-\d.e]+)\]"
)
ASSIGNED = re.compile(r"FR episode assigned .*?frontier=\[([-\d.e]+), ([-\d.e]+)\]")
LOCATE_WINDOW = 5  # episodes either side whose decision states can locate a frontier
LOCATE_PHI = 4.0  # φ units: a frontier is located when a decision state is this near it
BIN = 4.0  # width of the starting-distance bins, φ units
LAST_BIN = 20.0  # everything from here on is one bin


@functools.lru_cache(maxsize=4)  # --frontiers reads each log through both; callers only read
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


def frontiers(path):
    """{episode: frontier φ}: each "FR episode assigned" line belongs to the episode of the next
    FR decision line."""
    out, pending = {}, None
    with open(path, errors="replace") as lines:
        for line in lines:
            line = ANSI.sub("", line)
            assigned = ASSIGNED.search(line)
            if assigned:
                pending = (float(assigned[1]), float(assigned[2]))
                continue
            found = DECISION.search(line)
            if found and pending is not None:
                out[int(found[1])] = pending
                pending = None
    return out


def locate(found_all, phi, episode, window=LOCATE_WINDOW):
    """(xy, φ offset) of the decision state of episodes episode ± window whose φ is nearest
    to `phi`, or None when no such state is within LOCATE_PHI of it."""
    best = None
    for (other, _), (_, _, xy, state_phi, _) in found_all.items():
        if abs(other - episode) <= window:
            offset = math.dist(state_phi, phi)
            if best is None or offset < best[1]:
                best = (xy, offset)
    return best if best is not None and best[1] <= LOCATE_PHI else None


def through_wall(maze, xy, target_xy):
    """(target s, straight distance, through a wall) of a target at `target_xy` seen from `xy`."""
    target_s = maze.progress(*target_xy)
    straight = math.dist(xy, target_xy)
    return target_s, straight, abs(target_s - maze.progress(*xy)) - straight >= maze.size


def stuck_waypoints(path, maze, window=LOCATE_WINDOW):
    """One row per stuck walk: (episode, where it stuck as s, its last waypoint's s or None,
    straight distance or None, through a wall). The waypoint is located as a frontier is."""
    found_all = decisions(path)
    rows = []
    for episode, walk in sorted(walks(path).items()):
        t, x, y, switch = walk[-1]
        if switch != "Stuck":
            continue
        at = maze.progress(x, y)
        goals = [
            found_all[(episode, t_dec)][4]
            for t_dec, _, _, _ in walk
            if (episode, t_dec) in found_all and found_all[(episode, t_dec)][0] == "Waypoint"
        ]
        spot = locate(found_all, goals[-1], episode, window) if goals else None
        if spot is None:
            rows.append((episode, at, None, None, False))
        else:
            rows.append((episode, at, *through_wall(maze, (x, y), spot[0])))
    return rows


def frontier_switches(path, maze, window=LOCATE_WINDOW):
    """One row per near-frontier switch: (episode, switch s, frontier s or None, straight
    distance in metres or None, through a wall)."""
    found_all = decisions(path)
    assigned = frontiers(path)
    rows = []
    for episode, walk in sorted(walks(path).items()):
        t, x, y, switch = walk[-1]
        if switch != "NearFrontier" or episode not in assigned:
            continue
        at = maze.progress(x, y)
        spot = locate(found_all, assigned[episode], episode, window)
        if spot is None:
            rows.append((episode, at, None, None, False))
            continue
        rows.append((episode, at, *through_wall(maze, (x, y), spot[0])))
    return rows


def print_targets(rows, what, target, listing):
    """One summary line (and with `listing` one entry per row) of frontier_switches or
    stuck_waypoints rows."""
    located = [r for r in rows if r[2] is not None]
    if not located:
        print(f"  {what}: {len(rows)}, none with its {target} located")
        return
    walls = [r for r in located if r[4]]
    print(
        f"  {what}: {len(rows)}, {target} located for {len(located)} ({target} s median "
        f"{statistics.median(r[2] for r in located):.1f} m, walk s median "
        f"{statistics.median(r[1] for r in located):.1f} m); through a wall: {len(walls)}"
        + (
            f" (walk s median {statistics.median(r[1] for r in walls):.1f} m, {target} s "
            f"median {statistics.median(r[2] for r in walls):.1f} m, straight "
            f"{statistics.median(r[3] for r in walls):.1f} m)"
            if walls
            else ""
        )
    )
    if listing:
        print("    " + " ".join(
            f"e{e}:s{at:.0f}->" + ("?" if ts is None else f"{ts:.0f}{'W' if wall else ''}")
            for e, at, ts, _, wall in rows
        ))


def print_frontiers(path, maze, listing, window):
    rows = frontier_switches(path, maze, window)
    print_targets(rows, "near-frontier switches", "frontier", listing)
    print_targets(stuck_waypoints(path, maze, window), "stuck walks", "last waypoint", listing)


def median_or_dash(values, fmt="{:.0f}"):
    return fmt.format(statistics.median(values)) if values else "-"


def summarize(path, maze, by, listing, with_segments, with_frontiers=False, window=LOCATE_WINDOW):
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
    if with_frontiers:
        print_frontiers(path, maze, listing, window)


def main(argv):
    by, listing, with_segments, with_frontiers, paths, task = 500, False, False, False, [], "antmaze-u"
    window = LOCATE_WINDOW
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
        elif arg == "--frontiers":
            with_frontiers = True
        elif arg == "--window":
            window = int(next(args, "") or sys.exit("--window needs a number of episodes"))
        elif arg.startswith("-"):
            sys.exit(__doc__)
        else:
            paths.append(arg)
    if not paths:
        sys.exit(__doc__)
    maze = maze_path.for_task(task)
    for path in paths:
        summarize(path, maze, by, listing, with_segments, with_frontiers, window)


if __name__ == "__main__":
    main(sys.argv[1:])
