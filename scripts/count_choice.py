#!/usr/bin/env python3
"""Where HESS's count-based subgoal choice sends an ordinary episode, with and without the
frontier-reaching (FR) episodes' visits, replayed offline from a run's graph-service checkpoint.

    scripts/count_choice.py [--stretches A-B,...] [--decisions N] [--seed S] RUN_DIR...

In an ordinary episode most subgoals are HESS's count-based choice (graph-service, SPEC §6.4):
of 2000 stored states drawn at random, the one within 20 φ-units of the agent whose 3.0 φ-cell
has the smallest future count F (the discounted visits that the stored episodes passing through
the cell went on to make), plus 10 x the potential after episode 400. In ASI the FR episodes'
states are stored and counted like any other, so the cells near the frontier that FR walks
reach gain visits, and the choice may turn away from them. This replays the choice for the
decision states (env steps 20, 40, ...) of the run's ordinary episodes in each stretch, on the
newest checkpoint's store, with three future-count maps: `saved` from the checkpoint's visit
map (the counts the service held, FR visits included), and two built the same way from the
stored states, `all` counting every stored episode and `no FR` leaving the FR episodes out of
the visits and of the trajectories F is averaged over (`all` against `no FR` is the paired
comparison; `saved` against `all` shows what the recount changes). The same candidate draws serve both. Per stretch it
prints, for each map, the mean progress along the maze (scripts/maze_path.py) of the chosen
state minus that of the agent's state ("ahead", metres; negative: back toward the start) and
the share of choices ahead by more than 2 m; and how often the two maps chose differently.

Approximations, all shared by both maps: visits are recounted from the stored states under the
store's current φ (the service counts each state once, under the φ at its arrival; the script
prints how far its `all` recount is from the saved visit map), states of episodes 1-100 are not
counted (`exploration.explore_start_episode`), the potential is the checkpoint's (which the FR
segments fed too), and the 5-unit push is left out (it moves the subgoal outward from the agent,
not along the maze). Serial runs (one actor) whose store holds every episode. Standard library
only. Defaults: the whole run in stretches of 200 episodes, 400 decisions per stretch, seed 0.
"""
import math
import os
import random
import sys

import maze_path
from fr_outcomes import options
from store_reach import fr_episode_numbers, newest_checkpoint, read_store, read_tensors

CELL = 3.0  # exploration.count_cell_size
RADIUS = 20.0  # exploration.candidate_radius
N_CANDIDATES = 2000  # exploration.n_candidates
POTENTIAL_COEFF = 10.0  # exploration.potential_coeff
POTENTIAL_START = 400  # exploration.potential_start_episode
EXPLORE_START = 100  # exploration.explore_start_episode
C = 20  # hierarchy.c
GAMMA = 0.99  # exploration.future_count_discount
AHEAD_M = 2.0


def key(point):
    return (math.floor(point[0] / CELL), math.floor(point[1] / CELL))


def recount(trajectories, counted):
    """Visits per cell of the stored states of the episodes in `counted` (numbers) after
    EXPLORE_START, under the store's φ."""
    visits = {}
    for number, (latents, _) in trajectories.items():
        if number in counted and number > EXPLORE_START:
            for point in latents:
                k = key(point)
                visits[k] = visits.get(k, 0) + 1
    return visits


def future_map(trajectories, counted, visits):
    """F per cell from `visits`: for each trajectory in `counted` (episode numbers), its
    decision states' discounted future visits N_j = n_j + γ N_{j+1}; F = (sum of N + 1) /
    (samples + 1), the service's "intended" averaging; cells without a sample: F = 1."""
    sums = {}
    for number, (latents, _) in trajectories.items():
        if number not in counted:
            continue
        points = latents[C::C]
        n_future, following = [0.0] * len(points), 0.0
        for j in range(len(points) - 1, -1, -1):
            following = visits.get(key(points[j]), 0) + GAMMA * following
            n_future[j] = following
        for point, n in zip(points, n_future):
            k = key(point)
            total, count = sums.get(k, (0.0, 0))
            sums[k] = (total + n, count + 1)
    return {k: (total + 1.0) / (count + 1.0) for k, (total, count) in sums.items()}


def choose(start, draws, latents, score):
    """The index among `draws` that HESS picks from `start`: the lowest score among the draws
    within (0, RADIUS) of it, the first draw when none is."""
    best, best_score = None, None
    for index in draws:
        point = latents[index]
        d = math.dist(point, start)
        if 0.0 < d < RADIUS:
            s = score(point)
            if best_score is None or s < best_score:
                best, best_score = index, s
    return draws[0] if best is None else best


def load(run):
    """{episode number: (latents, xy)} of the newest checkpoint's store, every stored state's
    latent and xy (flat lists), and the potential map."""
    checkpoint = newest_checkpoint(run)
    store = read_store(checkpoint)
    obs, (n_states, obs_dim) = store["obs"]
    flat, _ = store["latents"]
    latents = [(flat[2 * j], flat[2 * j + 1]) for j in range(n_states)]
    xy = [(obs[obs_dim * j], obs[obs_dim * j + 1]) for j in range(n_states)]
    episodes, _ = store["episode"]
    lengths, _ = store["len"]
    trajectories, first = {}, 0
    for episode, length in zip(episodes, lengths):
        trajectories[episode + 1] = (latents[first:first + length], xy[first:first + length])
        first += length
    maps = read_tensors(os.path.join(checkpoint, "maps.safetensors"),
                        ["potential.keys", "potential.values", "visits.keys", "visits.values"])
    keys, _ = maps["potential.keys"]
    values, _ = maps["potential.values"]
    potential = {(keys[2 * i], keys[2 * i + 1]): v for i, v in enumerate(values)}
    keys, _ = maps["visits.keys"]
    values, _ = maps["visits.values"]
    saved_visits = {(keys[2 * i], keys[2 * i + 1]): v for i, v in enumerate(values)}
    return checkpoint, trajectories, latents, xy, potential, saved_visits


def replay(run, stretches, n_decisions, seed):
    checkpoint, trajectories, latents, xy, potential, saved_visits = load(run)
    maze = maze_path.for_run(run)
    fr = fr_episode_numbers(os.path.join(run, "metrics.jsonl"))
    numbers = set(trajectories)
    everyone = recount(trajectories, numbers)
    maps = {
        "saved": future_map(trajectories, numbers, saved_visits),
        "all": future_map(trajectories, numbers, everyone),
        "no FR": future_map(trajectories, numbers - fr, recount(trajectories, numbers - fr)),
    }
    off = sum(abs(everyone.get(k, 0) - saved_visits.get(k, 0)) for k in set(everyone) | set(saved_visits))
    print(f"== {run}: {len(trajectories)} stored episodes ({os.path.basename(checkpoint)}), {len(fr)} FR; "
          f"visits recounted under today's φ differ from the saved map by {off} of {sum(saved_visits.values())}")
    rng = random.Random(seed)
    for lo, hi in stretches:
        starts = [
            (number, j)
            for number, (points, _) in trajectories.items()
            if lo <= number <= hi and number not in fr
            for j in range(C, len(points), C)
        ]
        if not starts:
            continue
        sample = rng.sample(starts, min(n_decisions, len(starts)))
        with_potential = lo > POTENTIAL_START
        rows = {name: [] for name in maps}
        differ = 0
        for number, j in sample:
            start_latent = trajectories[number][0][j]
            start_s = maze.progress(*trajectories[number][1][j])
            draws = [rng.randrange(len(latents)) for _ in range(N_CANDIDATES)]
            chosen = {}
            for name, future in maps.items():
                def score(point, future=future):
                    k = key(point)
                    extra = POTENTIAL_COEFF * potential.get(k, 0.0) if with_potential else 0.0
                    return future.get(k, 1.0) + extra
                chosen[name] = choose(start_latent, draws, latents, score)
                rows[name].append(maze.progress(*xy[chosen[name]]) - start_s)
            differ += chosen["all"] != chosen["no FR"]
        parts = []
        for name, ahead in rows.items():
            mean = sum(ahead) / len(ahead)
            share = sum(a > AHEAD_M for a in ahead) / len(ahead)
            parts.append(f"{name}: ahead {mean:+.2f} m, {share:.0%} > {AHEAD_M:g} m")
        print(f"  {lo}-{hi}: {len(sample)} decisions of ordinary episodes | " + " | ".join(parts)
              + f" | different choice {differ / len(sample):.0%}")


def positive(text):
    """An int above 0 (ValueError otherwise)."""
    number = int(text)
    if number <= 0:
        raise ValueError("needs a positive number")
    return number


def main(args):
    stretches = [(101, 200), (201, 400), (401, 600), (601, 800), (801, 1000)]
    values = {"--decisions": (400, positive), "--seed": (0, int)}
    stretches, given, runs = options(args, set(), stretches, __doc__, values)
    for run in runs:
        replay(run, stretches, given["--decisions"], given["--seed"])
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
