#!/usr/bin/env python3
"""The launch history of run folders (`launches.jsonl`, written by `asi train`), and what in it
can make two runs of one seed part.

    scripts/launch_history.py RUN_DIR...

Prints, per run folder, one line per launch: when it started, the mode, the build (checksum
of the executable), the CPU, where it resumed from and whether that resume was bit-exact,
and how it ended (budget reached, stopped by a signal, failed, or no end line: killed or
still running). Then the notes of `notes()`: resumes that were not bit-exact, folders with
launches the history does not hold, and runs made by more than one build or CPU. A run
compared against another is only the uninterrupted run of its seed when no note names it;
`scripts/arm_table.py` prints the same notes under its tables.

Standard library only.
"""
import json
import os
import sys

FILE = "launches.jsonl"


def read(run_dir):
    """The records of `run_dir`'s history, oldest first; None when it has none. A line that
    does not parse (a launch killed while writing it) is skipped."""
    path = os.path.join(run_dir, FILE)
    if not os.path.exists(path):
        return None
    records = []
    with open(path) as lines:
        for line in lines:
            try:
                records.append(json.loads(line))
            except ValueError:
                continue
    return records


def launches(records):
    """{launch number: {"start": record, "resume": record, "end": record}} (keys present as
    written)."""
    out = {}
    for record in records:
        out.setdefault(record.get("launch"), {})[record.get("event")] = record
    return out


def point(p):
    if not p:
        return "fresh"
    episodes = p.get("episodes")
    return f"ckpt {p['checkpoint']} ({p['env_steps']} steps, {episodes if episodes is not None else '?'} episodes)"


def describe(records):
    """One line per launch of a folder's history."""
    rows = []
    for number, events in sorted(launches(records).items(), key=lambda kv: (kv[0] is None, kv[0])):
        start, resume, end = events.get("start", {}), events.get("resume"), events.get("end")
        resumed = point(start.get("resumed_from"))
        if resume is not None:
            resumed += ", exact" if resume.get("exact") else ", NOT exact"
        if end is None:
            ending = "no end line (killed, or running)"
        else:
            newest = end.get("checkpoint")
            ending = f"{end.get('outcome')}, " + (f"newest {point(newest)}" if newest else "no checkpoint")
            if end.get("error"):
                ending += f": {end['error']}"
        host = start.get("host", {})
        rows.append(
            f"  {number}: {start.get('at', '?')} {start.get('mode', '?')}, build "
            f"{start.get('binary', '?')}, {host.get('cpu', '?')}; from {resumed}; {ending}"
        )
    return rows


def notes(run_dirs):
    """What in the histories of `run_dirs` can make a run differ from the uninterrupted run of
    its seed with one build: a list of sentences, empty when nothing does."""
    out, builds, cpus, without = [], {}, {}, []
    for run in run_dirs:
        records = read(run)
        if records is None:
            without.append(run)
            continue
        for number, events in sorted(launches(records).items(), key=lambda kv: (kv[0] is None, kv[0])):
            start, resume = events.get("start", {}), events.get("resume")
            if start.get("earlier_launches_unrecorded"):
                out.append(f"{run}: the launches before launch {number} are not in its history")
            if resume is not None and not resume.get("exact"):
                out.append(
                    f"{run}: launch {number} resumed from {point(start.get('resumed_from'))} "
                    f"not bit-exactly ({resume.get('detail', '')})"
                )
            if "binary" in start:
                builds.setdefault(start["binary"], set()).add(run)
            cpu = start.get("host", {}).get("cpu")
            if cpu:
                cpus.setdefault(cpu, set()).add(run)
    if without:
        out.append(f"no launch history (runs from before it was recorded): {', '.join(without)}")
    for what, seen in (("builds", builds), ("CPU models", cpus)):
        if len(seen) > 1:
            parts = [f"{key}: {', '.join(sorted(runs))}" for key, runs in sorted(seen.items())]
            out.append(f"{len(seen)} {what} among these runs (" + "; ".join(parts) + ")")
    return out


def main(argv):
    if not argv or argv[0] in ("-h", "--help"):
        print(__doc__)
        return 0 if argv else 2
    for run in argv:
        if not os.path.isdir(run):
            print(f"{run}: not a folder", file=sys.stderr)
            return 2
    for run in argv:
        records = read(run)
        print(f"{run}:" if records is not None else f"{run}: no launch history")
        for row in describe(records or []):
            print(row)
    found = notes(argv)
    if found:
        print("\nnotes:")
        for note in found:
            print(f"- {note}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
