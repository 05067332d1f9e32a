#!/usr/bin/env python3
"""When and where frontier-reaching (FR) walks end, from the actor's FR decision trace.

    scripts/fr_trace.py [--by T] [--list] LOG...

Each LOG is the output of an AntMaze run started with `RUST_LOG=info,actor=debug` (serial mode
or an actor's log): every FR decision is a line "FR decision episode=E t=T xy=Some([x, y]) ...
switch=S". Unlike scripts/fr_outcomes.py, which sees one FR episode per metrics line, this
reads every decision, so it also gives *when* navigation ended (the env step of the stuck or
near-frontier switch) and how far the walk had got by step T (`--by`, default 500: how far it
would have got in a 500-step episode).

Per LOG: FR episodes; how navigation ended (stuck, near the frontier, or no switch before the
episode's end, which includes the rare FR mode ended by a new φ: the trace does not show that);
the median env step of the stuck and near-frontier switches; the median distance s along the
U's centreline (scripts/fr_outcomes.py's `along_u`) where navigation ended and the furthest s
by step T. `--list` also prints each episode's end as (x, y) t<step><S|N|->.
Standard library only.
"""
import re
import statistics
import sys

from fr_outcomes import along_u

ANSI = re.compile(r"\x1b\[[0-9;]*m")
DECISION = re.compile(
    r"FR decision episode=(\d+) t=(\d+) xy=Some\(\[([-\d.e]+), ([-\d.e]+)\]\).*?"
    r"switch=(None|Some\((\w+)\))"
)


def walks(path):
    """{episode: [(t, x, y, switch or None), ...]} up to and including the first switch."""
    episodes = {}
    with open(path, errors="replace") as lines:
        for line in lines:
            found = DECISION.search(ANSI.sub("", line))
            if not found:
                continue
            episode = int(found[1])
            decisions = episodes.setdefault(episode, [])
            if decisions and decisions[-1][3] is not None:
                continue  # count mode after the switch: not navigation
            decisions.append((int(found[2]), float(found[3]), float(found[4]), found[6]))
    return episodes


def median_or_dash(values, fmt="{:.0f}"):
    return fmt.format(statistics.median(values)) if values else "-"


def summarize(path, by, listing):
    episodes = walks(path)
    if not episodes:
        print(f"{path}: no FR decisions (was it run with RUST_LOG=info,actor=debug?)")
        return
    ends = [decisions[-1] for decisions in episodes.values()]
    stuck = [t for t, _, _, switch in ends if switch == "Stuck"]
    near = [t for t, _, _, switch in ends if switch == "NearFrontier"]
    running = len(ends) - len(stuck) - len(near)
    end_s = [along_u(x, y) for _, x, y, _ in ends]
    furthest = [
        max((along_u(x, y) for t, x, y, _ in decisions if t <= by), default=0.0)
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


def main(argv):
    by, listing, paths = 500, False, []
    args = iter(argv)
    for arg in args:
        if arg == "--by":
            by = int(next(args, "500"))
        elif arg == "--list":
            listing = True
        elif arg.startswith("-"):
            sys.exit(__doc__)
        else:
            paths.append(arg)
    if not paths:
        sys.exit(__doc__)
    for path in paths:
        summarize(path, by, listing)


if __name__ == "__main__":
    main(sys.argv[1:])
