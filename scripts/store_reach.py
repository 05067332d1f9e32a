#!/usr/bin/env python3
"""How far each episode of a maze run went, read from the graph-service's trajectory store.

    scripts/store_reach.py [--stretches A-B,C-D,...] [--potential] RUN_DIR...

The coverage metric credits a cell to the first episode that enters it, so when two kinds of
episode share a run (FR and ordinary ones in ASI) the per-episode coverage gain
(`fr_outcomes.py --gain`) cannot tell an episode that went less far from one that went as far
but found the cells taken. This script measures every episode on its own. It reads the newest
checkpoint under RUN_DIR/checkpoints/graph-service/ (`store.safetensors`: every stored state's
observation, whose first two values are the torso's x, y, and each trajectory's episode and
length; docs/ARCHITECTURE.md) and the run's metrics.jsonl (which episodes were FR episodes:
those whose line shows `actor0/actor/fr/episodes` grown). Serial runs (one actor) only, and
only runs whose store still holds every episode (nothing evicted).

Per run and stretch of training episodes it prints, FR and ordinary episodes apart, the mean
of three figures per episode:
- `reach`: the furthest point along the maze from the start, s in metres
  (scripts/maze_path.py on the maze of the run's task; in AntMaze-U the test goal is at 24);
- `cells`: distinct free 0.6 m coverage cells the episode entered, on the grid of
  `charts/coverage` (docs/METRICS.md: from the goal box's low corner, (-2, -2) in AntMaze-U; a
  cell is free when its centre is in a free maze cell);
- `new`: of those, cells no earlier episode of the run had entered: the episode's coverage
  gain in cells. Summed over all episodes it is `charts/coverage_free_cells_visited` on the
  metrics line of the store's last episode, which the script checks (a mismatch means the store and the metric
  disagree, e.g. an evicted store);
- `moved`: how far the torso moved per 20 env steps (c, a high-level segment: the straight xy
  distance from the segment's first state to its last, averaged over the episode's segments),
  the robot's speed at the pace its subgoals are set;
- `new w/o FR`: cells no earlier *ordinary* episode had entered, as if the FR episodes'
  visits did not count. For an ordinary episode of ASI against an episode of HESS (which has
  no FR episodes, so there the two columns agree) it removes the bookkeeping: an ordinary
  episode that found cells an FR episode had entered first gets them back.

`--potential` also prints HESS's potential map (`maps.safetensors`: the summed reaching errors
of graph-chosen segments per 3.0 φ-cell, docs/ARCHITECTURE.md) by where its cells are in the
maze: each cell goes to the median s of the stored states whose latent point falls in it, and
the potential is summed per 2 m of s (cells without a stored state: "unplaced").

Standard library only. docs/RESULTS.md ("Why ASI's ordinary episodes explore less") was made
with it.
"""
import array
import functools
import json
import math
import os
import statistics
import struct
import sys

import maze_path
from fr_outcomes import options, records

COUNT_CELL = 3.0
SEGMENT = 20  # hierarchy.c: env steps per high-level decision
STRETCHES = [(101, 250), (251, 500)]
DTYPES = {"F32": "f", "F64": "d", "I32": "i", "U32": "I", "U64": "Q", "U8": "B"}


def read_tensors(path, names):
    """{name: (flat array, shape)} of the named tensors of a safetensors file (little-endian)."""
    with open(path, "rb") as handle:
        (header_len,) = struct.unpack("<Q", handle.read(8))
        header = json.loads(handle.read(header_len))
        out = {}
        for name in names:
            if name not in header:
                sys.exit(f"{path}: no tensor '{name}' (is this a graph-service checkpoint?)")
            entry = header[name]
            start, end = entry["data_offsets"]
            handle.seek(8 + header_len + start)
            values = array.array(DTYPES[entry["dtype"]])
            values.frombytes(handle.read(end - start))
            if sys.byteorder != "little":
                values.byteswap()
            out[name] = (values, entry["shape"])
        return out


def newest_checkpoint(run):
    folder = os.path.join(run, "checkpoints", "graph-service")
    try:
        names = sorted(n for n in os.listdir(folder) if n.startswith("ckpt-"))
    except OSError:
        names = []
    if not names:
        sys.exit(f"{run}: no graph-service checkpoint in {folder}")
    return os.path.join(folder, names[-1])


def fr_episode_numbers(metrics):
    """Actor 0's episode numbers (1-based, `actor/episodes`) that were FR episodes."""
    fr, before = set(), 0
    for record in records(metrics):
        count = record.get("actor0/actor/fr/episodes")
        if count is None or record.get("actor0/actor/episodes") is None:
            continue
        if count > before:
            fr.add(int(record["actor0/actor/episodes"]))
        before = count
    return fr


@functools.lru_cache(maxsize=1)
def read_store(checkpoint):
    """The trajectory store of a graph-service checkpoint (observations, latents, episode ids,
    lengths), read once: episode_figures and potential_by_s both need its largest tensor."""
    return read_tensors(os.path.join(checkpoint, "store.safetensors"), ["obs", "latents", "episode", "len"])


def episode_figures(checkpoint, maze, fr=frozenset()):
    """(episode number, reach, cells, new, new w/o FR, moved) per stored trajectory, in episode
    order; `maze`: the run's maze_path.MazePath; `fr`: the FR episodes' numbers."""
    store = read_store(checkpoint)
    obs, (_, obs_dim) = store["obs"]
    episodes, _ = store["episode"]
    lengths, _ = store["len"]
    starts, first = [], 0
    for length in lengths:
        starts.append(first)
        first += length
    seen, seen_ordinary, rows = set(), set(), []
    for index in sorted(range(len(episodes)), key=lambda i: episodes[i]):
        begin, end = starts[index], starts[index] + lengths[index]
        xy = [(obs[obs_dim * j], obs[obs_dim * j + 1]) for j in range(begin, end)]
        reach = max(maze.progress(x, y) for x, y in xy)
        cells = {maze.coverage_cell(x, y) for x, y in xy} - {None}
        number = episodes[index] + 1
        new, new_ordinary = len(cells - seen), len(cells - seen_ordinary)
        seen |= cells
        if number not in fr:
            seen_ordinary |= cells
        moves = [math.dist(xy[j], xy[j + SEGMENT]) for j in range(0, len(xy) - SEGMENT, SEGMENT)]
        moved = sum(moves) / len(moves) if moves else 0.0
        rows.append((number, reach, len(cells), new, new_ordinary, moved))
    return rows


def potential_by_s(checkpoint, maze):
    """({2 m bin start: summed potential}, unplaced potential, total potential)."""
    maps = read_tensors(os.path.join(checkpoint, "maps.safetensors"), ["potential.keys", "potential.values"])
    store = read_store(checkpoint)
    obs, (n_states, obs_dim) = store["obs"]
    latents, (_, latent_dim) = store["latents"]
    where = {}
    for j in range(n_states):
        key = tuple(math.floor(latents[latent_dim * j + i] / COUNT_CELL) for i in range(latent_dim))
        where.setdefault(key, []).append(maze.progress(obs[obs_dim * j], obs[obs_dim * j + 1]))
    keys, _ = maps["potential.keys"]
    values, _ = maps["potential.values"]
    bins, unplaced = {}, 0.0
    for i, value in enumerate(values):
        key = tuple(keys[latent_dim * i + k] for k in range(latent_dim))
        if key in where:
            start = 2 * int(statistics.median(where[key]) // 2)
            bins[start] = bins.get(start, 0.0) + value
        else:
            unplaced += value
    return bins, unplaced, sum(values)


def value_at(metrics, key, episodes):
    """`key` on the first line where actor 0 has finished `episodes` episodes (the store's
    count; a run trains on past its last graph-service checkpoint), else None."""
    for record in records(metrics):
        if record.get("actor0/actor/episodes") == episodes and key in record:
            return record[key]
    return None


def summary(rows):
    if not rows:
        return "-"
    n = len(rows)
    reach = sum(r[1] for r in rows) / n
    cells = sum(r[2] for r in rows) / n
    new = sum(r[3] for r in rows) / n
    new_ordinary = sum(r[4] for r in rows) / n
    moved = sum(r[5] for r in rows) / n
    return (f"n={n} reach {reach:.1f} m, cells {cells:.1f}, new {new:.2f}, new w/o FR {new_ordinary:.2f}, "
            f"moved {moved:.2f} m/{SEGMENT} steps")


def main(args):
    stretches, given, run_dirs = options(args, {"--potential"}, STRETCHES, __doc__)
    potential = "--potential" in given
    for run in run_dirs:
        checkpoint = newest_checkpoint(run)
        fr = fr_episode_numbers(os.path.join(run, "metrics.jsonl"))
        maze = maze_path.for_run(run)
        rows = episode_figures(checkpoint, maze, fr)
        print(f"== {run}: {len(rows)} stored episodes ({os.path.basename(checkpoint)}), {len(fr)} FR")
        covered = value_at(os.path.join(run, "metrics.jsonl"), "learner/charts/coverage_free_cells_visited", len(rows))
        if covered is not None and covered != sum(r[3] for r in rows):
            print(f"  warning: the episodes' new cells add up to {sum(r[3] for r in rows)}, "
                  f"charts/coverage_free_cells_visited says {covered:.0f}")
        for lo, hi in stretches:
            stretch = [r for r in rows if lo <= r[0] <= hi]
            if stretch:
                print(
                    f"  {lo}-{hi}: FR {summary([r for r in stretch if r[0] in fr])} | "
                    f"ordinary {summary([r for r in stretch if r[0] not in fr])}"
                )
        if potential:
            bins, unplaced, total = potential_by_s(checkpoint, maze)
            cells = " ".join(f"{s}-{s + 2}: {bins[s]:.0f}" for s in sorted(bins))
            print(f"  potential {total:.0f} (unplaced {unplaced:.0f}) by s: {cells}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
