#!/usr/bin/env python3
"""Test success of several runs side by side, from their evaluations.

    scripts/eval_table.py [--window A-B] [--at E1,E2,...] RUN_DIR...

For each run folder (or an archive of one, scripts/run_archive.py) it reads `eval.jsonl` (one
line per evaluation: `train_episodes`, `success_rate`, `mean_final_path_distance`) and
`metrics.jsonl` (for the env steps and coverage at an episode: the first line whose
`learner/schedule/train_episodes` reaches it), and prints one Markdown table, a column per
run, with:

- the evaluations and the last training episode evaluated;
- the first evaluation with success above 0: its episode, env steps and rate; the first at 1.0;
- over the evaluations of `--window A-B` (training episodes A to B, both included; default: all):
  how many, how many with success above 0 and their rates, the mean success rate and the mean
  final path distance to the goal;
- with `--at`, coverage (`learner/charts/coverage`) at each of those episodes.

An episode evaluated twice (a resumed run evaluates again the episode it resumed at) counts
once, its newest line. Standard library only.
"""
import argparse
import json
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

from run_archive import open_text  # noqa: E402

COVERAGE = "learner/charts/coverage"
ENV_STEPS = "learner/ingest/env_steps"
EPISODES = "learner/schedule/train_episodes"


def evaluations(run_dir):
    """{training episode: evaluation record}, the newest line for an episode evaluated twice."""
    by_episode = {}
    with open_text(os.path.join(run_dir, "eval.jsonl")) as lines:
        for line in lines:
            line = line.strip()
            if not line:
                continue
            record = json.loads(line)
            by_episode[int(record["train_episodes"])] = record
    return by_episode


def at_episodes(run_dir, episodes, key):
    """{episode: `key` on the first metrics line whose training episodes reach it}."""
    wanted = sorted(set(episodes))
    found = {}
    path = os.path.join(run_dir, "metrics.jsonl")
    if not os.path.exists(path) and not os.path.exists(path + ".gz"):
        return found
    with open_text(path) as lines:
        for line in lines:
            if not wanted:
                break
            try:
                record = json.loads(line)
            except ValueError:
                continue
            reached = record.get(EPISODES)
            if reached is None or key not in record:
                continue
            while wanted and reached >= wanted[0]:
                found[wanted.pop(0)] = record[key]
    return found


def summary(run_dir, window=None, at=()):
    """The figures of one run (see the module doc) as a dict."""
    evals = evaluations(run_dir)
    episodes = sorted(evals)
    first = next((e for e in episodes if evals[e]["success_rate"] > 0), None)
    full = next((e for e in episodes if evals[e]["success_rate"] >= 1.0), None)
    lo, hi = window if window else (min(episodes, default=0), max(episodes, default=0))
    inside = [e for e in episodes if lo <= e <= hi]
    rates = [evals[e]["success_rate"] for e in inside]
    distances = [evals[e]["mean_final_path_distance"] for e in inside]
    steps = at_episodes(run_dir, [first] if first is not None else [], ENV_STEPS)
    return {
        "evaluations": len(episodes),
        "last_episode": max(episodes, default=None),
        "first_success": first,
        "first_success_rate": evals[first]["success_rate"] if first is not None else None,
        "first_success_env_steps": int(steps[first]) if first in steps else None,
        "first_full": full,
        "window": (lo, hi),
        "window_evaluations": len(inside),
        "window_successes": [r for r in rates if r > 0],
        "window_mean_success": sum(rates) / len(rates) if rates else None,
        "window_mean_path_distance": sum(distances) / len(distances) if distances else None,
        "coverage": at_episodes(run_dir, at, COVERAGE),
    }


def fmt(value, digits=3):
    if value is None:
        return "–"
    if isinstance(value, float):
        return f"{value:.{digits}f}"
    return f"{value:,}"


def rows(summaries, at):
    """The table's rows: (label, one cell per run)."""
    lo, hi = summaries[0]["window"]
    out = [
        ("evaluations (last episode)", [f"{s['evaluations']} ({fmt(s['last_episode'])})" for s in summaries]),
        (
            "first test success: episode (env steps), rate",
            [
                "none"
                if s["first_success"] is None
                else f"{fmt(s['first_success'])} ({fmt(s['first_success_env_steps'])}), "
                f"{fmt(s['first_success_rate'], 1)}"
                for s in summaries
            ],
        ),
        ("first evaluation at 1.0", [fmt(s["first_full"]) if s["first_full"] is not None else "none" for s in summaries]),
        (
            f"evaluations of {fmt(lo)}–{fmt(hi)} with success (of)",
            [
                f"{len(s['window_successes'])} of {s['window_evaluations']}"
                + (f" ({', '.join(fmt(r, 1) for r in s['window_successes'])})" if s["window_successes"] else "")
                for s in summaries
            ],
        ),
        (f"mean test success, {fmt(lo)}–{fmt(hi)}", [fmt(s["window_mean_success"]) for s in summaries]),
        (
            f"mean final path distance (m), {fmt(lo)}–{fmt(hi)}",
            [fmt(s["window_mean_path_distance"], 1) for s in summaries],
        ),
    ]
    if at:
        out.append(
            (
                "coverage at " + " / ".join(fmt(e) for e in at) + " episodes",
                [" / ".join(fmt(s["coverage"].get(e)) for e in at) for s in summaries],
            )
        )
    return out


def table(run_dirs, summaries, at):
    """The Markdown table of `rows`, a column per run named by its folder."""
    names = [os.path.basename(os.path.normpath(d)) for d in run_dirs]
    lines = ["| | " + " | ".join(names) + " |", "|---|" + "---:|" * len(names)]
    for label, cells in rows(summaries, at):
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def parse_window(text):
    try:
        lo, hi = (int(x) for x in text.split("-"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"--window {text!r}: expected A-B, e.g. 2501-3600")
    if lo > hi:
        raise argparse.ArgumentTypeError(f"--window {text!r}: A is above B")
    return lo, hi


def parse_at(text):
    try:
        return [int(x) for x in text.split(",") if x]
    except ValueError:
        raise argparse.ArgumentTypeError(f"--at {text!r}: expected episodes, e.g. 500,1000")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("runs", nargs="+", metavar="RUN_DIR")
    parser.add_argument("--window", type=parse_window, help="training episodes A-B (default: all)")
    parser.add_argument("--at", type=parse_at, default=[], help="coverage at these episodes")
    args = parser.parse_args(argv)
    for run in args.runs:
        if not any(os.path.exists(os.path.join(run, f)) for f in ("eval.jsonl", "eval.jsonl.gz")):
            parser.error(f"{run}: no eval.jsonl (is it a run folder?)")
    summaries = [summary(run, args.window, args.at) for run in args.runs]
    print(table(args.runs, summaries, args.at))
    return 0


if __name__ == "__main__":
    sys.exit(main())
