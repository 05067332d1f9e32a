#!/usr/bin/env python3
"""Compact copies of run folders that can live in the repository, and a bit-exact check of a
rerun against them.

    scripts/run_archive.py pack --out results/runs/SET RUN_DIR...
    scripts/run_archive.py check ARCHIVE_DIR RUN_DIR...

Run folders hold checkpoints of hundreds of MB and live only on the machine that made them.
`pack` keeps what the analysis needs: for each RUN_DIR it writes `OUT/<folder name>/` with
`config.resolved.toml`, `eval.jsonl` and `launches.jsonl` as they are, `metrics.jsonl` as
`metrics.jsonl.gz` (gzip, no time stamp: packing the same file twice gives the same bytes;
a 500-episode Ant run is about 0.2 MB), and `archive.json` (where it came from, the SHA-256,
size and line count of every file before compression, the last training episode). A missing
optional file is left out; a folder without `metrics.jsonl` or `config.resolved.toml` is an
error, and nothing is written for any folder until all have been read.

An archived folder is read like a run folder: `asi plot`, scripts/arm_table.py,
scripts/fr_outcomes.py (and the scripts built on its readers) open `metrics.jsonl.gz` when
`metrics.jsonl` is absent (`open_text`).

`check` compares each RUN_DIR's `metrics.jsonl` with `ARCHIVE_DIR/<folder name>/` line by
line. Serial runs are bit-exact (docs/ARCHITECTURE.md), so a rerun of an archived serial run
with the same command and build must give the same lines: it prints `same` (with how many
lines, and whether one of the two is a prefix of the other, a rerun stopped earlier or run
further), or the first line that differs and the keys whose values differ there, and exits 1
when any run differs. Standard library only.
"""
import argparse
import gzip
import hashlib
import json
import os
import shutil
import sys

METRICS = "metrics.jsonl"
REQUIRED = ["config.resolved.toml", METRICS]
OPTIONAL = ["eval.jsonl", "launches.jsonl"]
MANIFEST = "archive.json"


def open_text(path):
    """`path` opened as text, or its packed form `path.gz` when only that exists."""
    if not os.path.exists(path) and os.path.exists(path + ".gz"):
        return gzip.open(path + ".gz", "rt")
    return open(path)


def describe(path):
    """SHA-256, bytes and lines of a file."""
    digest, size, lines = hashlib.sha256(), 0, 0
    with open(path, "rb") as handle:
        for chunk in iter(lambda: handle.read(1 << 20), b""):
            digest.update(chunk)
            size += len(chunk)
            lines += chunk.count(b"\n")
    return {"sha256": digest.hexdigest(), "bytes": size, "lines": lines}


def last_train_episode(path):
    """The largest `learner/schedule/train_episodes` in a metrics file (None if none)."""
    last = None
    with open_text(path) as lines:
        for line in lines:
            try:
                value = json.loads(line).get("learner/schedule/train_episodes")
            except (ValueError, AttributeError):
                continue
            if value is not None:
                last = int(value) if last is None else max(last, int(value))
    return last


def pack(run_dirs, out):
    """Archive every run folder of `run_dirs` under `out` (see the module doc)."""
    plans = []
    names = set()
    for run in run_dirs:
        name = os.path.basename(os.path.normpath(run))
        if name in names:
            raise SystemExit(f"two run folders are named {name}: pack them into different --out folders")
        names.add(name)
        missing = [f for f in REQUIRED if not os.path.isfile(os.path.join(run, f))]
        if missing:
            raise SystemExit(f"{run}: not a run folder (no {', '.join(missing)})")
        files = REQUIRED + [f for f in OPTIONAL if os.path.isfile(os.path.join(run, f))]
        manifest = {
            "source": os.path.abspath(run),
            "files": {f: describe(os.path.join(run, f)) for f in files},
            "train_episodes": last_train_episode(os.path.join(run, METRICS)),
        }
        plans.append((run, name, files, manifest))
    for run, name, files, manifest in plans:
        target = os.path.join(out, name)
        os.makedirs(target, exist_ok=True)
        for f in files:
            if f == METRICS:
                with open(os.path.join(run, f), "rb") as src, open(os.path.join(target, f + ".gz"), "wb") as raw:
                    with gzip.GzipFile(filename="", mode="wb", compresslevel=9, fileobj=raw, mtime=0) as dst:
                        shutil.copyfileobj(src, dst)
                stale = os.path.join(target, f)
                if os.path.exists(stale):
                    os.remove(stale)
            else:
                shutil.copyfile(os.path.join(run, f), os.path.join(target, f))
        with open(os.path.join(target, MANIFEST), "w") as handle:
            json.dump(manifest, handle, indent=1, sort_keys=True)
            handle.write("\n")
        packed = os.path.getsize(os.path.join(target, METRICS + ".gz"))
        print(
            f"{name}: {manifest['files'][METRICS]['lines']} lines, to episode {manifest['train_episodes']}, "
            f"metrics {manifest['files'][METRICS]['bytes'] / 1e6:.2f} MB -> {packed / 1e6:.2f} MB"
        )


def differing_keys(a, b):
    """Keys whose values differ between two JSON lines (or None when one does not parse)."""
    try:
        x, y = json.loads(a), json.loads(b)
    except ValueError:
        return None
    if not isinstance(x, dict) or not isinstance(y, dict):
        return None
    return sorted(k for k in set(x) | set(y) if x.get(k) != y.get(k))


def compare(archived, rerun):
    """(same, message) for two metrics files, line by line."""
    with open_text(archived) as a, open_text(rerun) as b:
        number = 0
        while True:
            left, right = a.readline(), b.readline()
            if not left or not right:
                if not left and not right:
                    return True, f"same ({number} lines)"
                longer = "the rerun" if right else "the archive"
                return True, f"same over the first {number} lines ({longer} goes on)"
            number += 1
            if left != right:
                keys = differing_keys(left, right)
                what = "a line that is not JSON" if keys is None else ", ".join(keys[:8]) + (" ..." if len(keys) > 8 else "")
                return False, f"line {number} differs: {what}"


def check(archive, run_dirs):
    """Exit status 0 when every run's metrics equal its archive's (or one is a prefix)."""
    status = 0
    for run in run_dirs:
        name = os.path.basename(os.path.normpath(run))
        archived = os.path.join(archive, name, METRICS)
        if not os.path.exists(archived) and not os.path.exists(archived + ".gz"):
            print(f"{name}: not in {archive}")
            status = 1
            continue
        same, message = compare(archived, os.path.join(run, METRICS))
        print(f"{name}: {message}")
        if not same:
            status = 1
    return status


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    commands = parser.add_subparsers(dest="command", required=True)
    packing = commands.add_parser("pack", help="archive run folders")
    packing.add_argument("--out", required=True, help="folder to write one archived folder per run into")
    packing.add_argument("runs", nargs="+", metavar="RUN_DIR")
    checking = commands.add_parser("check", help="compare reruns with an archive")
    checking.add_argument("archive", metavar="ARCHIVE_DIR")
    checking.add_argument("runs", nargs="+", metavar="RUN_DIR")
    args = parser.parse_args(argv)
    if args.command == "pack":
        pack(args.runs, args.out)
        return 0
    return check(args.archive, args.runs)


if __name__ == "__main__":
    sys.exit(main())
