#!/usr/bin/env python3
"""One metric of several arms and seeds, by training episode, with paired differences.

    scripts/arm_table.py --at 150,200,300 [--metric M] [--base ARM] [--over A-B] [--factorial]
        RUN_DIR...

Runs are grouped into arms by folder name without the `_s<seed>` tag, as `asi plot` does
(runs/ant-u/asi_s0 and runs/ant-u/asi_s1 are seeds 0 and 1 of arm `asi`). For every arm it
prints the metric (default `learner/charts/coverage`) at each episode of `--at`: the value on
the first metrics.jsonl line whose `learner/schedule/train_episodes` reaches that episode,
the mean over the seeds in bold and each seed in brackets, as the tables of docs/RESULTS.md.
With `--base ARM` (e.g. hess) it adds, for every other arm, the paired difference arm − base
(same seed) at each episode, mean ± sample standard deviation over the seeds both arms have,
and over `--over A-B` (default: the first to the last episode of `--at`) the mean paired
difference of the per-episode values and the number of episodes where the seed mean of the
arm is above the base's. With `--factorial` it reads the four arms of claim 1 (asi,
asi-no-fr, asi-no-si, hess) as a two-by-two design, FR on or off by SI on or off: at each
episode of `--at`, FR's effect with SI on and off, SI's with FR on and off, and their
interaction (FR with SI − FR without SI), paired by seed over the seeds that have all four
arms there, mean ± sd with the one-sample t statistic; then each seed's values at the last
episode. With `--pool ARM=OTHER[,OTHER...]` (repeatable) the runs of the OTHER arms count
as more runs of ARM (e.g. `--pool asi=asi-null`: a null fork is another run of ASI): each
seed's value at an episode is then the mean over that seed's runs, `-` until all of them have
reached it, and every table reads the pooled arm. Standard library only; a run that has not
reached an episode shows `-` there. Under the tables, the notes of scripts/launch_history.py on the runs' launch
histories (resumes that were not bit-exact, several builds or CPUs), when there are any.
"""
import argparse
import json
import os
import re
import statistics
import sys
from collections import defaultdict

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import launch_history  # noqa: E402
from run_archive import open_text  # noqa: E402


def per_episode(path, metric):
    """{training episode: metric value} from the first line that reached each episode (of
    metrics.jsonl, or of its packed form, scripts/run_archive.py)."""
    values = {}
    with open_text(path) as lines:
        for line in lines:
            try:
                record = json.loads(line)
            except ValueError:
                continue  # a line cut by a kill
            episode = record.get("learner/schedule/train_episodes")
            value = record.get(metric)
            if episode is None or value is None:
                continue
            episode = int(episode)
            if episode not in values:
                values[episode] = float(value)
    return values


def at_or_after(values, episode):
    """The value of the first recorded episode >= `episode`, or None."""
    later = [e for e in values if e >= episode]
    return values[min(later)] if later else None


def fill(values, lo, hi):
    """Per-episode values over [lo, hi] by the rule of `at_or_after`, up to the last recorded
    episode (a line can cover several episodes when they are shorter than the metrics
    interval)."""
    out, following = {}, None
    for episode in range(min(hi, max(values, default=lo - 1)), lo - 1, -1):
        if episode in values:
            following = values[episode]
        if following is not None:
            out[episode] = following
    return out


def pool(arms, arm, others):
    """Makes the runs of `others` more runs of `arm`: each seed's per-episode values become the
    mean over its runs, at the episodes all of them have reached (by the rule of `at_or_after`)."""
    runs = defaultdict(list)
    for name in [arm, *others]:
        for seed, values in arms[name].items():
            runs[seed].append(values)
    merged = {}
    for seed, values in sorted(runs.items()):
        lo = min(min(v, default=0) for v in values)
        filled = [fill(v, lo, max(v, default=lo - 1)) for v in values]
        shared = set.intersection(*(set(f) for f in filled))
        merged[seed] = {e: statistics.mean(f[e] for f in filled) for e in sorted(shared)}
    kept = [(name, merged if name == arm else seeds) for name, seeds in arms.items()
            if name not in others]
    arms.clear()
    arms.update(kept)


def mean_sd(xs):
    if not xs:
        return "-"
    sd = statistics.stdev(xs) if len(xs) > 1 else 0.0
    return f"{statistics.mean(xs):+.3f} ± {sd:.3f}"


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("runs", nargs="+", metavar="RUN_DIR")
    parser.add_argument("--at", required=True, help="episodes, comma separated")
    parser.add_argument("--metric", default="learner/charts/coverage")
    parser.add_argument("--base", help="arm the others are paired against (e.g. hess)")
    parser.add_argument("--over", help="episode range FIRST-LAST for the whole-run figures")
    parser.add_argument("--factorial", action="store_true",
                        help="FR × SI table of the arms " + ", ".join(FACTORIAL_ARMS))
    parser.add_argument("--pool", action="append", default=[], metavar="ARM=OTHER[,OTHER...]",
                        help="count the runs of OTHER as more runs of ARM, averaged by seed")
    args = parser.parse_args()
    try:
        at = [int(e) for e in args.at.split(",")]
        lo, hi = (int(v) for v in args.over.split("-")) if args.over else (at[0], at[-1])
    except ValueError:
        parser.error("--at takes episodes like 150,200 and --over a range like 101-500")

    arms = defaultdict(dict)  # arm -> seed -> {episode: value}
    for run in args.runs:
        name = run.rstrip("/").split("/")[-1]
        match = re.fullmatch(r"(.*)_s(\d+)", name)
        arm, seed = (match.group(1), int(match.group(2))) if match else (name, 0)
        arms[arm][seed] = per_episode(f"{run}/metrics.jsonl", args.metric)
    pooled = {}  # arm -> the arms pooled into it
    for spec in args.pool:
        arm, _, others = spec.partition("=")
        others = [o for o in others.split(",") if o]
        unknown = [a for a in [arm, *others] if a not in arms]
        if not others or unknown:
            parser.error(f"--pool {spec}: takes ARM=OTHER[,OTHER...] with arms among "
                         f"{sorted(arms)}" + (f" (no run of {', '.join(unknown)})" if unknown else ""))
        pool(arms, arm, others)
        pooled[arm] = pooled.get(arm, []) + others
    if args.base and args.base not in arms:
        parser.error(f"--base {args.base}: no run of that arm among {sorted(arms)}")
    missing = [a for a in FACTORIAL_ARMS if a not in arms]
    if args.factorial and missing:
        parser.error(f"--factorial: no run of {', '.join(missing)} among {sorted(arms)}")

    print(f"{args.metric}, mean over seeds (seeds in brackets), by training episode")
    print("| arm | " + " | ".join(str(e) for e in at) + " |")
    for arm, seeds in arms.items():
        cells = []
        for episode in at:
            vals = [at_or_after(seeds[s], episode) for s in sorted(seeds)]
            got = [v for v in vals if v is not None]
            each = " / ".join("-" if v is None else f"{v:.3f}" for v in vals)
            cells.append(f"**{statistics.mean(got):.3f}** ({each})" if got else "-")
        also = f"; pooled with {', '.join(pooled[arm])}" if arm in pooled else ""
        print(f"| {arm} (seeds {', '.join(map(str, sorted(seeds)))}{also}) | " + " | ".join(cells) + " |")
    if args.base:
        paired(arms, args.base, at, lo, hi)
    if args.factorial:
        factorial(arms, at)
    found = launch_history.notes(args.runs)
    if found:
        print("\nlaunch histories (scripts/launch_history.py):")
        for note in found:
            print(f"- {note}")
    return 0


def paired(arms, base_arm, at, lo, hi):
    """The table of paired differences against `base_arm`."""

    base = arms[base_arm]
    print(f"\npaired difference arm − {base_arm} (mean ± sd over seeds)")
    print("| arm | " + " | ".join(str(e) for e in at) + f" | mean over {lo}–{hi} | episodes above |")
    for arm, seeds in arms.items():
        if arm == base_arm:
            continue
        common = sorted(set(seeds) & set(base))
        cells = []
        for episode in at:
            diffs = []
            for s in common:
                a, b = at_or_after(seeds[s], episode), at_or_after(base[s], episode)
                if a is not None and b is not None:
                    diffs.append(a - b)
            cells.append(mean_sd(diffs))
        run_means, above, counted = [], 0, 0
        filled = {s: (fill(seeds[s], lo, hi), fill(base[s], lo, hi)) for s in common}
        for s, (a, b) in filled.items():
            shared = sorted(set(a) & set(b))
            if shared:
                run_means.append(statistics.mean(a[e] - b[e] for e in shared))
        for episode in range(lo, hi + 1):
            pairs = [(a[episode], b[episode]) for a, b in filled.values() if episode in a and episode in b]
            if len(pairs) == len(common) and pairs:
                counted += 1
                above += statistics.mean(p[0] - p[1] for p in pairs) > 1e-12  # not float noise
        print(f"| {arm} | " + " | ".join(cells) + f" | {mean_sd(run_means)} | {above} of {counted} |")


FACTORIAL_ARMS = ("asi", "asi-no-fr", "asi-no-si", "hess")
# Each row of the FR × SI table: its name and the signs of asi, asi-no-fr, asi-no-si, hess.
FACTORIAL_ROWS = (
    ("FR with SI on (asi − asi-no-fr)", (1, -1, 0, 0)),
    ("FR with SI off (asi-no-si − hess)", (0, 0, 1, -1)),
    ("SI with FR on (asi − asi-no-si)", (1, 0, -1, 0)),
    ("SI with FR off (asi-no-fr − hess)", (0, 1, 0, -1)),
    ("interaction (FR with SI − FR without SI)", (1, -1, -1, 1)),
)


def t_statistic(xs):
    """Mean over its standard error; None for fewer than two values or no spread."""
    if len(xs) < 2 or statistics.stdev(xs) == 0:
        return None
    return statistics.mean(xs) / (statistics.stdev(xs) / len(xs) ** 0.5)


def factorial(arms, at):
    """The FR × SI table: each row's paired contrast at each episode of `at`, over the seeds
    with all four arms there; then each seed's contrasts at the last episode."""

    def contrasts(episode):
        """{seed: [contrast of each row]} for the seeds with all four arms at `episode`."""
        out = {}
        for seed in sorted(set.intersection(*(set(arms[a]) for a in FACTORIAL_ARMS))):
            values = [at_or_after(arms[a][seed], episode) for a in FACTORIAL_ARMS]
            if None not in values:
                out[seed] = [sum(c * v for c, v in zip(signs, values)) for _, signs in FACTORIAL_ROWS]
        return out

    by_episode = {episode: contrasts(episode) for episode in at}
    print("\nFR × SI, paired by seed (mean ± sd over seeds, t = mean / standard error)")
    print("| difference | " + " | ".join(str(e) for e in at) + " |")
    for row, (name, _) in enumerate(FACTORIAL_ROWS):
        cells = []
        for episode in at:
            xs = [c[row] for c in by_episode[episode].values()]
            t = t_statistic(xs)
            cells.append(mean_sd(xs) + ("" if t is None else f" (t = {t:.2f})"))
        print(f"| {name} | " + " | ".join(cells) + " |")
    print("| seeds | " + " | ".join(", ".join(map(str, by_episode[e])) or "-" for e in at) + " |")
    last = by_episode[at[-1]]
    print(f"\nby seed at {at[-1]} ({' / '.join(map(str, last))})")
    for row, (name, _) in enumerate(FACTORIAL_ROWS):
        print(f"| {name} | " + " / ".join(f"{c[row]:+.3f}" for c in last.values()) + " |")


if __name__ == "__main__":
    sys.exit(main())
