#!/usr/bin/env python3
"""Tests of the analysis scripts (fr_trace.py with --frontiers, fr_outcomes.py (with --far-goals), store_reach.py, maze_path.py,
count_choice.py, launch_history.py, arm_table.py's notes, its FR × SI table and its pooled arms, run_archive.py) on hand-built inputs, and of paper_arms.sh's forking with a stand-in for `asi train`.

    python3 scripts/test_analysis.py

Standard library only; .ci/run runs it when python3 is installed. Every expected figure is
computed by hand in the comments.
"""
import gzip
import json
import math
import os
import shutil
import struct
import subprocess
import sys
import tempfile
import unittest

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import fr_outcomes  # noqa: E402
import count_choice  # noqa: E402
import eval_table  # noqa: E402
import fr_trace  # noqa: E402
import launch_history  # noqa: E402
import maze_path  # noqa: E402
import run_archive  # noqa: E402
import store_reach  # noqa: E402

# The `maze` object of `asi tasks antmaze-u --json` (the entries the scripts read).
U_MAZE = {
    "rows": ["#####", "#S..#", "###.#", "#G..#", "#####"],
    "cell_size_m": 4.0,
    "robot_cell": [1, 1],
    "goal_box": [[-2.0, -2.0], [10.0, 10.0]],
}


def decision(episode, t, xy, phi, choice, subgoal, switch="None"):
    """One actor debug line, with the colour codes tracing puts around field names."""
    return (
        f"2026-12-02T19:45:56Z \x1b[34mDEBUG\x1b[0m actor::episode: FR decision "
        f"\x1b[3mepisode\x1b[0m\x1b[2m=\x1b[0m{episode} t={t} xy=Some([{xy[0]}, {xy[1]}]) "
        f"phi=[{phi[0]}, {phi[1]}] choice={choice} subgoal=[{subgoal[0]}, {subgoal[1]}] "
        f"switch={switch} route_len=9\n"
    )


def waypoint(k, index, cut=None):
    """The choice as the actor logs it; builds since `asi.fr_waypoint_straightness` add `cut`."""
    tail = "" if cut is None else f", cut: {cut}"
    return f"Waypoint {{ k: {k}, index: Some({index}){tail} }}"


class TraceSegments(unittest.TestCase):
    def setUp(self):
        lines = [
            # Episode 1: φ (0, 0) -> (3, 4) -> (6, 8), waypoints at route indices 4 then 5.
            decision(1, 0, (0.0, 0.0), (0.0, 0.0), waypoint(4, 4), (6.0, 8.0)),
            decision(1, 20, (0.3, 0.4), (3.0, 4.0), waypoint(4, 5, cut="false"), (8.0, 8.0)),
            # A count-mode decision after the switch: starts no navigation segment.
            decision(1, 40, (0.6, 0.8), (6.0, 8.0), "Count { fallback: false }", (1.0, 1.0), "Some(Stuck)"),
            decision(1, 60, (0.6, 0.8), (6.0, 8.0), "Count { fallback: false }", (1.0, 1.0)),
            # Episode 2: one segment that moves away from its waypoint (12 units away).
            decision(2, 0, (0.0, 0.0), (0.0, 0.0), waypoint(3, 3), (12.0, 0.0)),
            decision(2, 20, (-0.1, 0.0), (-1.0, 0.0), "Count { fallback: false }", (0.0, 0.0), "Some(Stuck)"),
            "an unrelated log line\n",
        ]
        handle = tempfile.NamedTemporaryFile("w", suffix=".log", delete=False)
        handle.writelines(lines)
        handle.close()
        self.path = handle.name

    def tearDown(self):
        os.unlink(self.path)

    def test_segments(self):
        rows = sorted(fr_trace.segments(fr_trace.decisions(self.path)))
        # Episode 1, t=0: start |(0,0)-(6,8)| = 10, end |(3,4)-(6,8)| = 5: ratio 0.5, φ moved 5,
        # xy moved 0.5, closed 5. t=20: start |(3,4)-(8,8)| = √41, end |(6,8)-(8,8)| = 2.
        # Episode 2: start 12, end 13: ratio 13/12, φ moved 1, xy 0.1, closed -1.
        # The count decisions (t=40 of episode 1) start no segment.
        self.assertEqual(len(rows), 3)
        expected = [
            (41 ** 0.5, 2 / 41 ** 0.5, 5.0, 0.5, 41 ** 0.5 - 2),
            (10.0, 0.5, 5.0, 0.5, 5.0),
            (12.0, 13 / 12, 1.0, 0.1, -1.0),
        ]
        for row, want in zip(rows, expected):
            for got, value in zip(row, want):
                self.assertAlmostEqual(got, value, places=5)

    def test_route_hops(self):
        # Episode 1 saw indices 4 -> (6, 8) and 5 -> (8, 8): one hop of length 2. Episode 2 saw
        # one index only.
        self.assertEqual(fr_trace.route_hops(fr_trace.decisions(self.path)), [2.0])

    def test_walks_stop_at_the_switch(self):
        walks = fr_trace.walks(self.path)
        # Episode 1's walk ends at the stuck switch at t=40; the later count decision is dropped.
        self.assertEqual([d[0] for d in walks[1]], [0, 20, 40])
        self.assertEqual(walks[1][-1][3], "Stuck")


def assigned(frontier):
    """The actor's debug line that assigns an FR episode its frontier (φ) and route."""
    return (
        f"2026-12-05T12:29:21Z \x1b[34mDEBUG\x1b[0m actor::actor: FR episode assigned "
        f"\x1b[3mactor\x1b[0m\x1b[2m=\x1b[0m0 frontier=[{frontier[0]}, {frontier[1]}] "
        f"route=[[0.0, 0.0], [{frontier[0]}, {frontier[1]}]]\n"
    )


class TraceFrontiers(unittest.TestCase):
    """Where near-frontier switches fire relative to their frontier, on the U maze: s = 0 at
    (0, 0), 4 at (4, 0), 8 at (8, 0), 12 at (8, 4), 16 at (8, 8), 20 at (4, 8), 24 at (0, 8);
    the wall between the two arms is the cell row y = 2..6, x < 6."""

    def setUp(self):
        near = "Some(NearFrontier)"
        count = "Count { fallback: false }"
        lines = [
            # Episode 3: frontier φ (40, 40); it switches at (4, 0.5), s = 4, φ (35, 35).
            assigned((40.0, 40.0)),
            decision(3, 0, (0.0, 0.0), (0.0, 0.0), waypoint(2, 2), (10.0, 0.0)),
            decision(3, 20, (4.0, 0.5), (35.0, 35.0), count, (36.0, 36.0), near),
            # Episode 4, same frontier: a waypoint decision at (4, 8) (s = 20) with φ (40, 41),
            # 1 from the frontier, locates it there for episodes 3 and 4; it switches at (8, 6),
            # s = 14, φ (38, 39) (its φ is √5 ≈ 2.2 from the frontier: (4, 8) is nearer).
            assigned((40.0, 40.0)),
            decision(4, 0, (4.0, 8.0), (40.0, 41.0), waypoint(2, 2), (40.0, 40.0)),
            decision(4, 20, (8.0, 6.0), (38.0, 39.0), count, (39.0, 39.0), near),
            # Episode 5: a frontier no decision state comes within 4 φ of; a stuck walk
            # (episode 6, no assigned line) is not a near-frontier switch.
            assigned((100.0, 100.0)),
            decision(5, 0, (0.0, 0.0), (0.0, 0.0), waypoint(2, 2), (10.0, 0.0)),
            decision(5, 20, (8.0, 0.0), (20.0, 20.0), count, (21.0, 21.0), near),
            decision(6, 0, (0.0, 0.0), (0.0, 0.0), waypoint(2, 2), (10.0, 0.0), "Some(Stuck)"),
            # Episode 7: a walk stuck at (4, 0.5), s = 4, whose last waypoint φ (40, 40.5) is
            # located at (4, 8), s = 20, by episode 4's state: 7.5 m through the wall.
            decision(7, 0, (2.0, 0.0), (1.0, 1.0), waypoint(3, 3), (40.0, 40.5)),
            decision(7, 20, (4.0, 0.5), (36.0, 36.0), count, (37.0, 37.0), "Some(Stuck)"),
            # Episode 12, frontier φ (40, 40) again: 8 episodes from episode 4, so located only
            # with a window of 8 or more; its switch at (8, 0.5), s = 8.5 (in the corner cell,
            # nearest the centreline's piece going down).
            assigned((40.0, 40.0)),
            decision(12, 0, (0.0, 0.0), (30.0, 30.0), waypoint(2, 2), (35.0, 35.0)),
            decision(12, 20, (8.0, 0.5), (33.0, 33.0), count, (34.0, 34.0), near),
        ]
        handle = tempfile.NamedTemporaryFile("w", suffix=".log", delete=False)
        handle.writelines(lines)
        handle.close()
        self.path = handle.name
        self.maze = maze_path.MazePath(U_MAZE)

    def tearDown(self):
        os.unlink(self.path)

    def test_frontiers_belong_to_the_next_decision(self):
        self.assertEqual(
            fr_trace.frontiers(self.path),
            {3: (40.0, 40.0), 4: (40.0, 40.0), 5: (100.0, 100.0), 12: (40.0, 40.0)},
        )

    def test_switches_through_a_wall(self):
        rows = fr_trace.frontier_switches(self.path, self.maze)
        self.assertEqual([r[0] for r in rows], [3, 4, 5, 12])
        # Episode 3: switch s 4, frontier at (4, 8), s 20; straight |(4, 0.5)-(4, 8)| = 7.5,
        # along 16: 8.5 shorter, more than a cell (4): through the wall.
        self.assertEqual(rows[0][1:3], (4.0, 20.0))
        self.assertAlmostEqual(rows[0][3], 7.5)
        self.assertTrue(rows[0][4])
        # Episode 4: switch s 14, frontier s 20; straight |(8, 6)-(4, 8)| = √20 ≈ 4.47, along
        # 6: 1.53 shorter, round the corner.
        self.assertEqual(rows[1][1:3], (14.0, 20.0))
        self.assertAlmostEqual(rows[1][3], 20 ** 0.5)
        self.assertFalse(rows[1][4])
        # Episode 5: nearest state φ (20, 20), 113 from the frontier: not located.
        self.assertEqual(rows[2][1:], (8.0, None, None, False))
        # Episode 12 with the default window (±5: episodes 7-17): the nearest state is episode
        # 7's φ (36, 36), 5.7 from the frontier: not located.
        self.assertEqual(rows[3][1:], (8.5, None, None, False))

    def test_a_wider_window_locates_more(self):
        rows = fr_trace.frontier_switches(self.path, self.maze, window=8)
        # Episode 12 now sees episode 4's φ (40, 41): frontier at (4, 8), s 20; straight
        # |(8, 0.5)-(4, 8)| = √72.25 = 8.5, along 11.5: 3 shorter, less than a cell.
        self.assertEqual(rows[3][1:3], (8.5, 20.0))
        self.assertAlmostEqual(rows[3][3], 8.5)
        self.assertFalse(rows[3][4])

    def test_stuck_walks_and_their_last_waypoint(self):
        rows = fr_trace.stuck_waypoints(self.path, self.maze)
        # Episode 6: stuck at (0, 0), s 0; its waypoint φ (10, 0) is 10 from the nearest state
        # (φ (0, 0)): not located. Episode 7: stuck at s 4, waypoint at (4, 8), s 20, 7.5 m
        # away in a straight line: through the wall.
        self.assertEqual([r[0] for r in rows], [6, 7])
        self.assertEqual(rows[0][1:], (0.0, None, None, False))
        self.assertEqual(rows[1][1:3], (4.0, 20.0))
        self.assertAlmostEqual(rows[1][3], 7.5)
        self.assertTrue(rows[1][4])


class CoverageGains(unittest.TestCase):
    def test_gains_split_fr_and_ordinary(self):
        records = [
            # (train episode, actor episodes, FR episodes, coverage)
            (1, 1, 0, 0.10),
            (2, 2, 1, 0.13),   # FR, +0.03
            (3, 3, 1, 0.14),   # ordinary, +0.01
            (5, 5, 1, 0.20),   # two episodes apart: skipped
            (6, 6, 2, 0.25),   # FR, +0.05
        ]
        handle = tempfile.NamedTemporaryFile("w", suffix=".jsonl", delete=False)
        for train, episodes, fr, coverage in records:
            handle.write(json.dumps({
                "learner/schedule/train_episodes": train,
                "actor0/actor/episodes": episodes,
                "actor0/actor/fr/episodes": fr,
                "learner/charts/coverage": coverage,
            }) + "\n")
        handle.write("{cut by a kill\n")
        handle.close()
        try:
            gains = fr_outcomes.coverage_gains(handle.name)
        finally:
            os.unlink(handle.name)
        self.assertEqual([(e, fr) for e, fr, _ in gains], [(2, True), (3, False), (6, True)])
        for (_, _, got), want in zip(gains, [0.03, 0.01, 0.05]):
            self.assertAlmostEqual(got, want, places=9)


class OutcomeCounts(unittest.TestCase):
    def test_each_stretch_counts_the_rise_of_the_counters(self):
        # (train episode, near frontier, stuck, new phi, navigating at end)
        records = [
            (3, 0, 0, 0, 0),
            (5, 1, 0, 0, 1),
            (8, 2, 1, 0, 1),
            (10, 4, 1, 1, 2),
            (14, 4, 3, 1, 2),
        ]
        handle = tempfile.NamedTemporaryFile("w", suffix=".jsonl", delete=False)
        handle.write(json.dumps({"learner/schedule/train_episodes": 1}) + "\n")  # before FR
        for train, *counts in records:
            record = {"learner/schedule/train_episodes": train}
            for code, count in enumerate(counts):
                record["actor0/actor/fr/" + fr_outcomes.OUTCOME_COUNTERS[code]] = count
            handle.write(json.dumps(record) + "\n")
        handle.write("{cut by a kill\n")
        handle.close()
        try:
            got = fr_outcomes.outcome_counts(handle.name, [(1, 5), (6, 10), (11, 20), (30, 40)])
        finally:
            os.unlink(handle.name)
        # 1-5: zeros before -> line 5; 6-10: line 5 -> line 10; 11-20: line 10 -> line 14;
        # 30-40 lies after the last line and is left out.
        self.assertEqual(got, {(1, 5): [1, 0, 0, 1], (6, 10): [3, 1, 1, 1], (11, 20): [0, 2, 0, 0]})

    def test_runs_without_the_counters_give_nothing(self):
        handle = tempfile.NamedTemporaryFile("w", suffix=".jsonl", delete=False)
        handle.write(json.dumps({"learner/schedule/train_episodes": 4, "actor0/actor/fr/last_outcome": 1}) + "\n")
        handle.close()
        try:
            self.assertEqual(fr_outcomes.outcome_counts(handle.name, [(1, 10)]), {})
        finally:
            os.unlink(handle.name)


class FarGoalSuccesses(unittest.TestCase):
    def test_successes_split_fr_and_ordinary_across_a_window_close(self):
        # Windows of 3 episodes, success unit 1: count_prob after a window with x successes is
        # 1/(1 + exp(2x - 1)).
        p = lambda x: 1.0 / (1.0 + math.exp(2 * x - 1))
        records = [
            # (train episode, FR episodes, window episodes, window successes, count_prob)
            (1, 0, 1, 0, 1.0),
            (2, 1, 2, 1, 1.0),    # FR, succeeded: 0 -> 1
            (3, 1, 0, 0, p(2)),   # ordinary, closed the window with 2 successes: 2 - 1 = 1
            (4, 2, 1, 0, p(2)),   # FR, no success
            (6, 2, 0, 0, p(0)),   # two episodes after the last: skipped
            (7, 2, 1, 1, p(0)),   # ordinary, succeeded
        ]
        handle = tempfile.NamedTemporaryFile("w", suffix=".jsonl", delete=False)
        for train, fr, length, successes, count_prob in records:
            handle.write(json.dumps({
                "learner/schedule/train_episodes": train,
                "actor0/actor/fr/episodes": fr,
                "learner/schedule/window_episodes": length,
                "learner/schedule/window_far_goal_successes": successes,
                "learner/schedule/count_prob": count_prob,
            }) + "\n")
        handle.close()
        try:
            got = fr_outcomes.far_goal_successes(handle.name, 1.0)
        finally:
            os.unlink(handle.name)
        self.assertEqual(got, [(2, True, 1), (3, False, 1), (4, True, 0), (7, False, 1)])

    def test_success_unit_from_the_run_config(self):
        with tempfile.TemporaryDirectory() as run:
            self.assertEqual(fr_outcomes.config_value(run, "count_prob_success_unit", 5.0), 5.0)
            with open(f"{run}/config.resolved.toml", "w") as f:
                f.write("[exploration]\ncount_prob_interval_episodes = 50\ncount_prob_success_unit = 2.5\n")
            self.assertEqual(fr_outcomes.config_value(run, "count_prob_success_unit", 5.0), 2.5)


class MazePath(unittest.TestCase):
    def test_progress_along_the_u(self):
        u = maze_path.MazePath(U_MAZE)
        # Centreline (0,0) -> (8,0) -> (8,8) -> (0,8); straight stretches give the coordinate
        # along them: 4 in the first arm, 8 + y in the right arm, 16 + (8 - x) in the last.
        for (x, y), s in [((4.0, 0.5), 4.0), ((8.5, 4.0), 12.0), ((2.0, 8.0), 22.0), ((0.0, 8.0), 24.0)]:
            self.assertAlmostEqual(u.progress(x, y), s, places=9)
        # Behind the start and beyond the goal's centre: clamped to the ends.
        self.assertEqual(u.progress(-1.0, 0.5), 0.0)
        self.assertEqual(u.progress(-1.5, 9.0), 24.0)
        # Corner cell (8, 0): (7.5, 0.2) is 0.2 from the piece in (y = 0) and 0.5 from the
        # piece out (x = 8): s = 7.5; (8.2, 1.5) is nearer the piece out: 8 + 1.5.
        self.assertAlmostEqual(u.progress(7.5, 0.2), 7.5, places=9)
        self.assertAlmostEqual(u.progress(8.2, 1.5), 9.5, places=9)
        # In the inner wall block (cell (2, 1)) the nearest free centres are (0, 0) and (4, 0),
        # 3.6 m away; the start cell comes first: (2, 3) projects to (2, 0), s = 2.
        self.assertAlmostEqual(u.progress(2.0, 3.0), 2.0, places=9)

    def test_progress_on_a_ring_takes_the_shorter_way(self):
        # 1 m cells; the goal cell (3, 3), centre (2, 2), is 4 steps from the start both ways.
        ring = maze_path.MazePath({
            "rows": ["#####", "#S..#", "#.#.#", "#..G#", "#####"],
            "cell_size_m": 1.0,
            "robot_cell": [1, 1],
            "goal_box": [[-0.5, -0.5], [2.5, 2.5]],
        })
        self.assertEqual(ring.steps[(3, 3)], 4)
        self.assertAlmostEqual(ring.progress(2.0, 2.0), 4.0, places=9)
        # 0.3 m before the goal's centre, coming from (3, 2): 3.5 + 0.2.
        self.assertAlmostEqual(ring.progress(1.7, 2.0), 3.7, places=9)
        # Down the left side: (0, 1) is one step from the start, (0, 2) two.
        self.assertAlmostEqual(ring.progress(0.0, 1.0), 1.0, places=9)
        self.assertAlmostEqual(ring.progress(0.0, 2.0), 2.0, places=9)

    def test_coverage_cells_follow_the_metric_grid(self):
        u = maze_path.MazePath(U_MAZE)
        # 0.6 m cells from (-2, -2): (0.1, 0.1) -> (3, 3); (8.5, 4.0) -> (17, 10).
        self.assertEqual(u.coverage_cell(0.1, 0.1), (3, 3))
        self.assertEqual(u.coverage_cell(8.5, 4.0), (17, 10))
        # 12 m / 0.6 m is 20 cells (not 21 by rounding); the far edge is in the last one.
        self.assertEqual(u.coverage_cell(10.0, 10.0), (19, 19))
        # The inner wall block and outside the goal box: no cell.
        self.assertIsNone(u.coverage_cell(2.0, 3.0))
        self.assertIsNone(u.coverage_cell(-2.5, 0.0))

    @unittest.skipUnless(
        os.environ.get("ASI_BIN") or any(
            os.access(os.path.join(maze_path.ROOT, "target", p, "asi"), os.X_OK) for p in ("release", "debug")
        ),
        "no asi binary (cargo test builds target/debug/asi)",
    )
    def test_the_binary_describes_the_same_u(self):
        maze_path.for_task.cache_clear()
        u = maze_path.for_task("antmaze-u")
        self.assertEqual((u.rows, u.size, u.robot), (U_MAZE["rows"], 4.0, (1, 1)))
        self.assertEqual(u.goal_box, ((-2.0, -2.0), (10.0, 10.0)))
        self.assertEqual(u.progress(0.0, 8.0), 24.0)


def write_safetensors(path, tensors):
    """A safetensors file of {name: (dtype, shape, flat values)}, little-endian."""
    codes = {"F32": "f", "F64": "d", "I32": "i", "U64": "Q"}
    header, blobs, offset = {}, [], 0
    for name, (dtype, shape, values) in tensors.items():
        blob = struct.pack(f"<{len(values)}{codes[dtype]}", *values)
        header[name] = {"dtype": dtype, "shape": shape, "data_offsets": [offset, offset + len(blob)]}
        blobs.append(blob)
        offset += len(blob)
    text = json.dumps(header).encode()
    with open(path, "wb") as handle:
        handle.write(struct.pack("<Q", len(text)) + text + b"".join(blobs))


class StoreReach(unittest.TestCase):
    def setUp(self):
        self.run = tempfile.mkdtemp()
        checkpoint = os.path.join(self.run, "checkpoints", "graph-service", "ckpt-000002")
        os.makedirs(checkpoint)
        os.makedirs(os.path.join(self.run, "checkpoints", "graph-service", "ckpt-000001"))
        # Observations of dimension 3 (x, y, something). Stored out of order: the trajectory of
        # episode id 1 first (3 states), then episode id 0 (2 states).
        states = [
            (0.1, 0.1), (8.5, 4.0), (8.5, 4.1),  # episode 2: s up to 12; cells (3,3), (17,10), (17,10)
            (0.0, 0.0), (2.0, 3.0),              # episode 1: (3,3); (2, 3) is in the wall block
        ]
        obs = [v for x, y in states for v in (x, y, 9.0)]
        latents = [0.5, 0.5, 4.0, 4.0, 4.5, 4.5, 1.0, 1.0, 2.0, 2.0]
        write_safetensors(os.path.join(checkpoint, "store.safetensors"), {
            "obs": ("F32", [5, 3], obs),
            "latents": ("F32", [5, 2], latents),
            "episode": ("U64", [2], [1, 0]),
            "len": ("U64", [2], [3, 2]),
        })
        # φ-cells of side 3: (0, 0) holds states at s 0.1, 0 and 2 -> median 0.1; (1, 1) holds
        # the two states at s 12 and 12.1 -> median 12.05; (5, 5) holds none.
        write_safetensors(os.path.join(checkpoint, "maps.safetensors"), {
            "potential.keys": ("I32", [3, 2], [0, 0, 1, 1, 5, 5]),
            "potential.values": ("F64", [3], [2.0, 5.0, 7.0]),
        })
        with open(os.path.join(self.run, "metrics.jsonl"), "w") as handle:
            for episodes, fr, cells in [(1, 0, 1), (2, 1, 2)]:
                handle.write(json.dumps({
                    "actor0/actor/episodes": episodes,
                    "actor0/actor/fr/episodes": fr,
                    "learner/charts/coverage_free_cells_visited": cells,
                }) + "\n")
        self.checkpoint = checkpoint
        store_reach.read_store.cache_clear()  # a temporary folder's name can come back

    def tearDown(self):
        import shutil
        shutil.rmtree(self.run)

    def test_newest_checkpoint_and_fr_episodes(self):
        self.assertEqual(store_reach.newest_checkpoint(self.run), self.checkpoint)
        self.assertEqual(store_reach.fr_episode_numbers(os.path.join(self.run, "metrics.jsonl")), {2})

    def test_episode_figures(self):
        u = maze_path.MazePath(U_MAZE)
        rows = store_reach.episode_figures(self.checkpoint, u)
        # Episode 1: reach max(s(0, 0), s(2, 3)) = 2 (a wall point counts in the nearest free
        # cell, MazePath's test); one free cell, (3,3), new. Episode 2: reach s(8.5, 4.1) =
        # 12.1; free cells (3,3) and (17,10), the second new.
        self.assertEqual([r[0] for r in rows], [1, 2])
        self.assertEqual([r[2:5] for r in rows], [(1, 1, 1), (2, 1, 1)])
        # Both episodes are shorter than one 20-step segment: nothing moved per segment.
        self.assertEqual([r[5] for r in rows], [0.0, 0.0])
        # With episode 1 an FR episode, its cell (3,3) does not count against episode 2's
        # "new w/o FR": both of episode 2's cells are new to the ordinary episodes.
        rows = store_reach.episode_figures(self.checkpoint, u, fr={1})
        self.assertEqual([r[2:5] for r in rows], [(1, 1, 1), (2, 1, 2)])
        self.assertAlmostEqual(rows[0][1], 2.0)
        self.assertAlmostEqual(rows[1][1], 12.1, places=5)

    def test_potential_by_s(self):
        bins, unplaced, total = store_reach.potential_by_s(self.checkpoint, maze_path.MazePath(U_MAZE))
        self.assertEqual(bins, {0: 2.0, 12: 5.0})
        self.assertEqual((unplaced, total), (7.0, 14.0))

    def test_store_read_once(self):
        # Both figures of one checkpoint come from one read of store.safetensors (an Ant
        # store's observations are hundreds of megabytes); the maps file is read apart.
        reads = []
        original = store_reach.read_tensors

        def counting(path, names):
            reads.append(os.path.basename(path))
            return original(path, names)

        store_reach.read_tensors = counting
        try:
            u = maze_path.MazePath(U_MAZE)
            store_reach.episode_figures(self.checkpoint, u)
            store_reach.potential_by_s(self.checkpoint, u)
        finally:
            store_reach.read_tensors = original
        self.assertEqual(reads.count("store.safetensors"), 1)
        self.assertEqual(reads.count("maps.safetensors"), 1)


class SegmentMoves(unittest.TestCase):
    def test_moved_per_segment(self):
        # One 41-state episode walking +0.1 m in x per step from (0, 0.5): segments 0->20 and
        # 20->40 both move 2.0 m; the last state starts no segment of its own.
        run = tempfile.mkdtemp()
        checkpoint = os.path.join(run, "ckpt-000001")
        os.makedirs(checkpoint)
        xy = [(0.1 * j, 0.5) for j in range(41)]
        write_safetensors(os.path.join(checkpoint, "store.safetensors"), {
            "obs": ("F32", [41, 2], [v for p in xy for v in p]),
            "latents": ("F32", [41, 2], [0.0] * 82),
            "episode": ("U64", [1], [0]),
            "len": ("U64", [1], [41]),
        })
        store_reach.read_store.cache_clear()
        try:
            rows = store_reach.episode_figures(checkpoint, maze_path.MazePath(U_MAZE))
        finally:
            import shutil
            shutil.rmtree(run)
            store_reach.read_store.cache_clear()
        self.assertEqual(len(rows), 1)
        self.assertAlmostEqual(rows[0][5], 2.0, places=5)
        self.assertAlmostEqual(rows[0][1], 4.0, places=5)  # reach: x = 4.0 along the first arm


class CountChoice(unittest.TestCase):
    @staticmethod
    def trajectories():
        # Episode numbers 100-102, 41 states each, all in one 3.0-cell: 100 and 101 in (0, 0),
        # 102 in (1, 0). The xy parts are not used here.
        return {
            100: ([(0.5, 0.5)] * 41, None),
            101: ([(0.5, 0.5)] * 41, None),
            102: ([(3.5, 0.5)] * 41, None),
        }

    def test_visits_count_after_the_explore_start_only(self):
        trajectories = self.trajectories()
        self.assertEqual(count_choice.recount(trajectories, {100, 101, 102}), {(0, 0): 41, (1, 0): 41})
        self.assertEqual(count_choice.recount(trajectories, {100}), {})

    def test_future_map_by_hand(self):
        trajectories = self.trajectories()
        visits = count_choice.recount(trajectories, {101})
        # Episode 101's decision states are its states 20 and 40, both in (0, 0) with 41
        # visits: N_2 = 41, N_1 = 41 + 0.99 * 41 = 81.59; F = (41 + 81.59 + 1) / (2 + 1).
        future = count_choice.future_map(trajectories, {101}, visits)
        self.assertEqual(set(future), {(0, 0)})
        self.assertAlmostEqual(future[(0, 0)], (41 + 81.59 + 1) / 3, places=9)
        # Episode 102 in too, but its visits not counted: its samples in (1, 0) have N = 0,
        # so F = (0 + 0 + 1) / 3 there.
        future = count_choice.future_map(trajectories, {101, 102}, visits)
        self.assertAlmostEqual(future[(1, 0)], 1 / 3, places=9)

    def test_choose_takes_the_lowest_score_within_the_radius(self):
        latents = [(0.0, 0.0), (25.0, 0.0), (3.0, 0.0), (-3.0, 0.0)]
        scores = {(3.0, 0.0): 5.0, (-3.0, 0.0): 2.0}
        score = lambda p: scores.get(p, 0.0)  # noqa: E731
        # Draw 0 is the start itself (distance 0) and draw 1 is beyond 20: neither qualifies.
        self.assertEqual(count_choice.choose((0.0, 0.0), [0, 1, 2, 3], latents, score), 3)
        self.assertEqual(count_choice.choose((0.0, 0.0), [1, 0], latents, score), 1)


# Stand-in for `asi train --serial` as paper_arms.sh calls it (ASI_BIN): resumes at the run
# folder's last episode and writes one metrics line per episode up to run.max_episodes with the
# two switches (and SI's weight, where set) it ran under, so a test can read which switches each
# episode of an arm had.
FAKE_ASI = r"""#!/usr/bin/env python3
import json, os, sys
args = sys.argv[1:]
assert args[:2] == ["train", "--serial"], args
run_dir = args[args.index("--run-dir") + 1]
sets = dict(args[i + 1].split("=", 1) for i, a in enumerate(args) if a == "--set")
fr = sets.get("asi.frontier_reaching", "true") == "true"
si = sets.get("asi.self_imitation", "true") == "true"
os.makedirs(os.path.join(run_dir, "checkpoints", "serial"), exist_ok=True)
with open(os.path.join(run_dir, "config.resolved.toml"), "w") as out:
    out.write(open(args[args.index("--config") + 1]).read())
path = os.path.join(run_dir, "metrics.jsonl")
done = 0
if os.path.exists(path):
    for line in open(path):
        done = json.loads(line)["learner/schedule/train_episodes"]
# FAKE_STOP_AT plays a signal: the run stops there, short of run.max_episodes, and exits 0.
until = int(sets["run.max_episodes"])
until = min(until, int(os.environ.get("FAKE_STOP_AT", until)))
with open(path, "a") as out:
    for episode in range(done + 1, until + 1):
        out.write(json.dumps({"learner/schedule/train_episodes": episode, "fr": fr, "si": si,
                              "alpha": sets.get("asi.si_alpha")}) + "\n")
"""


class PaperArms(unittest.TestCase):
    """scripts/paper_arms.sh with FR_START 20, SI_START 30, 40 episodes and a stand-in binary."""

    def setUp(self):
        self.dir = tempfile.TemporaryDirectory()
        self.bin = os.path.join(self.dir.name, "fake-asi")
        with open(self.bin, "w") as f:
            f.write(FAKE_ASI)
        os.chmod(self.bin, 0o755)
        self.out = os.path.join(self.dir.name, "runs")
        # The fork points come from the config (FR_START / SI_START unset).
        self.config = os.path.join(self.dir.name, "config.toml")
        with open(self.config, "w") as f:
            f.write("[asi]\nfr_start_episode = 20  # FR from here\n# si_start_episode = 99\n"
                    "si_start_episode = 30\n")

    def tearDown(self):
        self.dir.cleanup()

    def arms(self, arms, **extra_env):
        script = os.path.join(os.path.dirname(os.path.abspath(__file__)), "paper_arms.sh")
        env = {k: v for k, v in os.environ.items() if k not in ("FR_START", "SI_START", "FAKE_STOP_AT")}
        env.update(ARMS=arms, ASI_BIN=self.bin, NICE="0", **extra_env)
        return subprocess.run(["bash", script, self.config, "0", "40", self.out], env=env,
                              capture_output=True, text=True, timeout=120)

    def assertRefused(self, done, message):
        """The script stopped with exit 2 and MESSAGE before running anything."""
        self.assertEqual(done.returncode, 2, done.stderr)
        self.assertIn(message, " ".join(done.stderr.split()))
        self.assertFalse(os.path.exists(self.out), "nothing ran")

    def switches(self, arm):
        """Runs of (first episode, last episode, FR on, SI on) in the arm's metrics."""
        runs = []
        with open(os.path.join(self.out, f"{arm}_s0", "metrics.jsonl")) as lines:
            for line in lines:
                m = json.loads(line)
                key = (m["fr"], m["si"])
                if runs and runs[-1][2:] == key and runs[-1][1] + 1 == m["learner/schedule/train_episodes"]:
                    runs[-1] = (runs[-1][0], runs[-1][1] + 1) + key
                else:
                    runs.append((m["learner/schedule/train_episodes"],) * 2 + key)
        return runs

    def test_each_arm_is_forked_at_its_switch(self):
        done = self.arms("asi asi-no-fr asi-no-si hess")
        self.assertEqual(done.returncode, 0, done.stderr)
        # The trunk runs FR off (SI on: it cannot act before SI_START), the branches from 20,
        # the arms from 30.
        trunk = (1, 20, False, True)
        self.assertEqual(self.switches("asi"), [trunk, (21, 40, True, True)])
        self.assertEqual(self.switches("asi-no-fr"), [(1, 40, False, True)])
        self.assertEqual(self.switches("asi-no-si"), [trunk, (21, 30, True, True), (31, 40, True, False)])
        self.assertEqual(self.switches("hess"), [(1, 30, False, True), (31, 40, False, False)])

    def test_archive_packs_the_seeds_folders_when_every_arm_is_done(self):
        archive = os.path.join(self.dir.name, "archive")
        done = self.arms("asi hess", ARCHIVE=archive)
        self.assertEqual(done.returncode, 0, done.stderr)
        self.assertEqual(sorted(os.listdir(archive)), ["asi-no-fr_s0", "asi_s0", "hess_s0", "trunk_s0"])
        for name in os.listdir(archive):
            with open(os.path.join(self.out, name, "metrics.jsonl")) as plain:
                packed = list(fr_outcomes.records(os.path.join(archive, name, "metrics.jsonl")))
                self.assertEqual(packed, [json.loads(line) for line in plain])
            # The trunk stops at FR_START, the FR-off branch at SI_START, the arms at 40.
            self.assertEqual(len(packed), {"trunk_s0": 20, "asi-no-fr_s0": 30}.get(name, 40), name)
        # A seed stopped short packs nothing.
        shutil.rmtree(self.out)
        shutil.rmtree(archive)
        done = self.arms("asi hess", ARCHIVE=archive, FAKE_STOP_AT="35")
        self.assertNotEqual(done.returncode, 0)
        self.assertFalse(os.path.exists(archive))

    def alphas(self, arm):
        """(first episode, last episode, asi.si_alpha given) runs in the arm's metrics."""
        runs = []
        with open(os.path.join(self.out, f"{arm}_s0", "metrics.jsonl")) as lines:
            for line in lines:
                m = json.loads(line)
                episode = m["learner/schedule/train_episodes"]
                if runs and runs[-1][2] == m["alpha"]:
                    runs[-1] = (runs[-1][0], episode, m["alpha"])
                else:
                    runs.append((episode, episode, m["alpha"]))
        return runs

    def test_the_null_fork_is_asi_with_alpha_times_1_01_from_si_start(self):
        done = self.arms("asi asi-null")
        self.assertEqual(done.returncode, 0, done.stderr)
        # ASI's prefix to SI_START (30), then the default α (0.01) times 1.01.
        self.assertEqual(self.switches("asi-null"), [(1, 20, False, True), (21, 40, True, True)])
        self.assertEqual(self.alphas("asi-null"), [(1, 30, None), (31, 40, "0.0101")])
        self.assertEqual(self.alphas("asi"), [(1, 40, None)])
        # A config's own α is the one scaled.
        shutil.rmtree(self.out)
        with open(self.config, "a") as f:
            f.write("si_alpha = 0.02  # SI's weight\n")
        self.assertEqual(self.arms("asi-null").returncode, 0)
        self.assertEqual(self.alphas("asi-null"), [(1, 30, None), (31, 40, "0.0202")])
        # Like asi-no-si it is forked from asi at 30, so not once asi has run on.
        on = self.arms("asi asi-null")
        self.assertEqual(on.returncode, 0, on.stderr)
        shutil.rmtree(os.path.join(self.out, "asi-null_s0"))
        late = self.arms("asi-null")
        self.assertNotEqual(late.returncode, 0)
        self.assertIn("cannot fork asi-null_s0 from asi_s0", " ".join(late.stderr.split()))

    def test_a_null_fork_needs_a_readable_alpha(self):
        with open(self.config, "a") as f:
            f.write("si_alpha = 1.2.3\n")
        self.assertRefused(self.arms("asi asi-null"), "si_alpha = 1.2.3 is not a number")
        # The other arms do not read it.
        self.assertEqual(self.arms("asi").returncode, 0)

    def test_an_arm_is_not_forked_from_a_branch_that_ran_on(self):
        done = self.arms("asi")
        self.assertEqual(done.returncode, 0, done.stderr)
        # asi_s0 is at 40 now: asi-no-si cannot be forked from it at 30 any more.
        late = self.arms("asi-no-si")
        self.assertNotEqual(late.returncode, 0)
        self.assertIn("cannot fork asi-no-si_s0 from asi_s0: that run is at episode 40, not at "
                      "the fork point 30", " ".join(late.stderr.split()))
        self.assertFalse(os.path.exists(os.path.join(self.out, "asi-no-si_s0")))
        # hess from the FR-off branch, still at 30, is fine.
        self.assertEqual(self.arms("hess").returncode, 0)
        self.assertEqual(self.switches("hess"), [(1, 30, False, True), (31, 40, False, False)])

    def test_a_stage_stopped_short_stops_the_script_and_resumes_on_a_rerun(self):
        # The trunk stops at 12 of 20: nothing is forked from it.
        stopped = self.arms("asi hess", FAKE_STOP_AT="12")
        self.assertEqual(stopped.returncode, 1)
        self.assertIn("trunk_s0: stopped at episode 12 of 20", stopped.stderr)
        self.assertFalse(os.path.exists(os.path.join(self.out, "asi_s0")))
        # The branches stop at 25 of 30 (both run, beside each other): no arm is forked.
        stopped = self.arms("asi hess", FAKE_STOP_AT="25")
        self.assertEqual(stopped.returncode, 1)
        self.assertIn("asi_s0: stopped at episode 25 of 30", stopped.stderr)
        self.assertIn("asi-no-fr_s0: stopped at episode 25 of 30", stopped.stderr)
        self.assertFalse(os.path.exists(os.path.join(self.out, "hess_s0")))
        # An arm stopping at 35 of 40 fails the script too, after the others end.
        stopped = self.arms("asi hess", FAKE_STOP_AT="35")
        self.assertEqual(stopped.returncode, 1)
        self.assertIn("hess_s0: stopped at episode 35 of 40", stopped.stderr)
        # The same command resumes every stage where it stopped.
        done = self.arms("asi hess")
        self.assertEqual(done.returncode, 0, done.stderr)
        self.assertEqual(self.switches("asi"), [(1, 20, False, True), (21, 40, True, True)])
        self.assertEqual(self.switches("hess"), [(1, 30, False, True), (31, 40, False, False)])

    def test_fork_points_other_than_the_configs_are_refused(self):
        self.assertRefused(self.arms("asi", FR_START="20", SI_START="25"),
                           "asi.fr_start_episode = 20 and asi.si_start_episode = 30")
        # Given by hand and equal to the config's, they are accepted.
        self.assertEqual(self.arms("asi", FR_START="20", SI_START="30").returncode, 0)

    def test_a_fork_point_that_is_not_an_integer_is_refused(self):
        # Read as anything but an integer it would be taken for the binary's default (300).
        with open(self.config, "w") as f:
            f.write("[asi]\nfr_start_episode = 20\nsi_start_episode = 30.5  # half way\n")
        self.assertRefused(self.arms("asi"), "si_start_episode = 30.5 is not an integer")


class Options(unittest.TestCase):
    VALUES = {"--decisions": (400, count_choice.positive), "--seed": (0, int)}

    def parse(self, args):
        return fr_outcomes.options(args, {"--gain"}, [(1, 2)], "usage", self.VALUES)

    def test_values_switches_and_runs(self):
        stretches, given, runs = self.parse(["--seed", "3", "a", "--stretches", "5-9", "--gain", "b"])
        self.assertEqual(stretches, [(5, 9)])
        self.assertEqual(given, {"--decisions": 400, "--seed": 3, "--gain": True})
        self.assertEqual(runs, ["a", "b"])
        _, given, _ = self.parse(["a"])
        self.assertNotIn("--gain", given)
        self.assertEqual(given["--decisions"], 400)

    def test_bad_input_exits_with_a_message(self):
        for args, message in [
            (["--decisions", "0", "a"], "--decisions 0: needs a positive number"),
            (["--seed", "x", "a"], "--seed x: invalid literal"),
            (["a", "--seed"], "--seed needs a value"),
            (["--bogus", "a"], "unknown option --bogus"),
        ]:
            with self.assertRaises(SystemExit) as caught:
                self.parse(args)
            self.assertIn(message, str(caught.exception.code), args)
        with self.assertRaises(SystemExit) as caught:
            self.parse(["--seed", "1"])
        self.assertEqual(caught.exception.code, 2)


def start(launch, resumed_from=None, binary="b1", cpu="Xeon", **extra):
    """A `start` line of launches.jsonl as `asi train` writes it (the fields the script reads)."""
    return {
        "event": "start", "launch": launch, "at": f"2026-12-05T0{launch}:00:00Z", "mode": "serial",
        "binary": binary, "host": {"cpu": cpu, "logical_cores": 2, "rayon_threads": "1"},
        "resumed_from": resumed_from, **extra,
    }


class LaunchHistory(unittest.TestCase):
    CKPT2 = {"checkpoint": 2, "env_steps": 1000, "episodes": 20}

    def setUp(self):
        self.tmp = tempfile.TemporaryDirectory()
        self.addCleanup(self.tmp.cleanup)

    def run_dir(self, name, records, broken_tail=False):
        path = os.path.join(self.tmp.name, name)
        os.makedirs(path)
        with open(os.path.join(path, "metrics.jsonl"), "w") as out:
            for episodes, coverage in ((10, 0.25), (20, 0.5)):
                out.write(json.dumps({"learner/schedule/train_episodes": episodes,
                                      "learner/charts/coverage": coverage}) + "\n")
        if records is not None:
            with open(os.path.join(path, "launches.jsonl"), "w") as out:
                out.writelines(json.dumps(r) + "\n" for r in records)
                if broken_tail:
                    out.write('{"event":"st')
        return path

    def three_runs(self):
        clean = self.run_dir("asi_s0", [
            start(0), {"event": "end", "launch": 0, "outcome": "stopped", "checkpoint": self.CKPT2},
            start(1, self.CKPT2), {"event": "resume", "launch": 1, "exact": True, "detail": "ok"},
            {"event": "end", "launch": 1, "outcome": "budget_reached", "checkpoint": None},
        ], broken_tail=True)
        inexact = self.run_dir("asi_s1", [
            start(0), start(1, self.CKPT2, binary="b2", cpu="EPYC"),
            {"event": "resume", "launch": 1, "exact": False, "detail": "2 open episodes are lost"},
        ])
        unrecorded = self.run_dir("hess_s0", [start(0, self.CKPT2, earlier_launches_unrecorded=True)])
        bare = self.run_dir("hess_s1", None)
        return clean, inexact, unrecorded, bare

    def test_notes_name_what_can_make_a_run_part_from_its_seed(self):
        clean, inexact, unrecorded, bare = self.three_runs()
        self.assertEqual(launch_history.notes([clean]), [], "exact resumes, one build, one CPU")
        found = launch_history.notes([clean, inexact, unrecorded, bare])
        self.assertEqual(found, [
            f"{inexact}: launch 1 resumed from ckpt 2 (1000 steps, 20 episodes) not bit-exactly "
            "(2 open episodes are lost)",
            f"{unrecorded}: the launches before launch 0 are not in its history",
            f"no launch history (runs from before it was recorded): {bare}",
            f"2 builds among these runs (b1: {', '.join(sorted([clean, inexact, unrecorded]))}; "
            f"b2: {inexact})",
            f"2 CPU models among these runs (EPYC: {inexact}; "
            f"Xeon: {', '.join(sorted([clean, inexact, unrecorded]))})",
        ])

    def test_one_line_per_launch_and_a_killed_line_is_skipped(self):
        clean, inexact, _, _ = self.three_runs()
        rows = launch_history.describe(launch_history.read(clean))
        self.assertEqual(rows, [
            "  0: 2026-12-05T00:00:00Z serial, build b1, Xeon; from fresh; "
            "stopped, newest ckpt 2 (1000 steps, 20 episodes)",
            "  1: 2026-12-05T01:00:00Z serial, build b1, Xeon; from ckpt 2 (1000 steps, 20 episodes), "
            "exact; budget_reached, no checkpoint",
        ])
        rows = launch_history.describe(launch_history.read(inexact))
        self.assertTrue(rows[0].endswith("no end line (killed, or running)"), rows)
        self.assertIn("NOT exact", rows[1])

    def test_arm_table_prints_the_notes_under_its_tables(self):
        clean, inexact, _, _ = self.three_runs()
        script = os.path.join(os.path.dirname(os.path.abspath(__file__)), "arm_table.py")
        out = subprocess.run([sys.executable, script, "--at", "20", clean, inexact],
                             capture_output=True, text=True, check=True).stdout
        self.assertIn("| asi (seeds 0, 1) | **0.500** (0.500 / 0.500) |", out)
        tail = out.split("launch histories (scripts/launch_history.py):\n")[1]
        self.assertTrue(tail.startswith(f"- {inexact}: launch 1 resumed from ckpt 2"), tail)
        out = subprocess.run([sys.executable, script, "--at", "20", clean],
                             capture_output=True, text=True, check=True).stdout
        self.assertNotIn("launch histories", out)


class Pool(unittest.TestCase):
    """arm_table.py --pool asi=asi-null: a null fork is one more run of ASI, averaged by seed."""

    # Coverage by episode. Seed 0: asi has 15, asi-null not, so at 15 the null fork's next
    # value (0.40 at 20) is taken: (0.50 + 0.40) / 2 = 0.45. Seed 1's null fork stops at 10,
    # so from 15 on the seed has no pooled value.
    RUNS = {"asi_s0": {10: 0.20, 15: 0.50, 20: 0.60}, "asi-null_s0": {10: 0.30, 20: 0.40},
            "asi_s1": {10: 0.30, 20: 0.50}, "asi-null_s1": {10: 0.10},
            "asi-no-fr_s0": {10: 0.25, 20: 0.45}, "asi-no-fr_s1": {10: 0.20, 20: 0.50}}

    def test_each_seed_is_the_mean_of_its_runs(self):
        script = os.path.join(os.path.dirname(os.path.abspath(__file__)), "arm_table.py")
        with tempfile.TemporaryDirectory() as tmp:
            for name, values in self.RUNS.items():
                os.makedirs(os.path.join(tmp, name))
                with open(os.path.join(tmp, name, "metrics.jsonl"), "w") as out:
                    for episode, coverage in values.items():
                        out.write(json.dumps({"learner/schedule/train_episodes": episode,
                                              "learner/charts/coverage": coverage}) + "\n")
            runs = [os.path.join(tmp, name) for name in self.RUNS]

            def table(*extra):
                return subprocess.run([sys.executable, script, "--at", "10,15,20", "--base",
                                       "asi-no-fr", *extra, *runs], capture_output=True, text=True)

            done = table("--pool", "asi=asi-null")
            self.assertEqual(done.returncode, 0, done.stderr)
            self.assertIn("| asi (seeds 0, 1; pooled with asi-null) | **0.225** (0.250 / 0.200) | "
                          "**0.450** (0.450 / -) | **0.500** (0.500 / -) |", done.stdout)
            self.assertNotIn("| asi-null", done.stdout)
            # Paired against ASI without FR: 0 and 0 at 10; seed 0 alone at 15 (0.45 − 0.45, its
            # next value) and at 20 (0.50 − 0.45).
            self.assertIn("| asi | +0.000 ± 0.000 | +0.000 ± 0.000 | +0.050 ± 0.000 |", done.stdout)
            # Unpooled, the null fork is an arm of its own.
            plain = table()
            self.assertIn("| asi (seeds 0, 1) | **0.250** (0.200 / 0.300) |", plain.stdout)
            self.assertIn("| asi-null (seeds 0, 1) | **0.200** (0.300 / 0.100) |", plain.stdout)
            # An arm with no run is an error.
            bad = table("--pool", "asi=hess")
            self.assertEqual(bad.returncode, 2)
            self.assertIn("--pool asi=hess", bad.stderr)
            self.assertIn("no run of hess", bad.stderr)


class Factorial(unittest.TestCase):
    """arm_table.py --factorial on two seeds of the four arms, coverage at episode 20."""

    # Coverage of asi, asi-no-fr, asi-no-si, hess. Seed 0: FR with SI on .60 − .50 = +.10,
    # FR with SI off .55 − .52 = +.03, SI with FR on .60 − .55 = +.05, SI with FR off
    # .50 − .52 = −.02, interaction .10 − .03 = +.07. Seed 1: −.05, +.04, −.10, −.01, −.09.
    # Means: +.025, +.035, −.025, −.015, −.010. Sample sd of two values is |a − b| / √2:
    # .15 / √2 = .106, .01 / √2 = .007, .106, .007, .16 / √2 = .113. t = mean / (sd / √2):
    # .025 / .075 = 0.33, .035 / .005 = 7.00, −0.33, −.015 / .005 = −3.00, −.010 / .08 = −0.125.
    COVERAGE = {0: (0.60, 0.50, 0.55, 0.52), 1: (0.40, 0.45, 0.50, 0.46)}

    def table(self, *runs):
        script = os.path.join(os.path.dirname(os.path.abspath(__file__)), "arm_table.py")
        return subprocess.run([sys.executable, script, "--at", "10,20", "--factorial", *runs],
                              capture_output=True, text=True)

    def test_the_two_by_two_contrasts_paired_by_seed(self):
        with tempfile.TemporaryDirectory() as tmp:
            runs = []
            for seed, values in self.COVERAGE.items():
                for arm, value in zip(("asi", "asi-no-fr", "asi-no-si", "hess"), values):
                    path = os.path.join(tmp, f"{arm}_s{seed}")
                    os.makedirs(path)
                    with open(os.path.join(path, "metrics.jsonl"), "w") as out:
                        for episode, coverage in ((10, 0.1), (20, value)):
                            out.write(json.dumps({"learner/schedule/train_episodes": episode,
                                                  "learner/charts/coverage": coverage}) + "\n")
                    runs.append(path)
            done = self.table(*runs)
            self.assertEqual(done.returncode, 0, done.stderr)
            table, by_seed = done.stdout.split("by seed at 20 (0 / 1)\n")
            rows = {line.split(" | ")[0].lstrip("| "): line for line in table.splitlines()}
            # At episode 10 every arm has 0.1: every contrast is 0 with no spread, so no t.
            self.assertEqual(rows["FR with SI on (asi − asi-no-fr)"],
                             "| FR with SI on (asi − asi-no-fr) | +0.000 ± 0.000 | +0.025 ± 0.106 (t = 0.33) |")
            self.assertIn("| +0.035 ± 0.007 (t = 7.00) |", rows["FR with SI off (asi-no-si − hess)"])
            self.assertIn("| -0.025 ± 0.106 (t = -0.33) |", rows["SI with FR on (asi − asi-no-si)"])
            self.assertIn("| -0.015 ± 0.007 (t = -3.00) |", rows["SI with FR off (asi-no-fr − hess)"])
            self.assertIn("| -0.010 ± 0.113 (t = -0.1", rows["interaction (FR with SI − FR without SI)"])
            self.assertIn("| seeds | 0, 1 | 0, 1 |", done.stdout)
            by_seed = by_seed.splitlines()
            self.assertEqual(by_seed[0], "| FR with SI on (asi − asi-no-fr) | +0.100 / -0.050 |")
            self.assertEqual(by_seed[4], "| interaction (FR with SI − FR without SI) | +0.070 / -0.090 |")
            # A seed without all four arms is left out; an arm missing everywhere is an error.
            done = self.table(*runs[:-1])
            self.assertIn("| seeds | 0 | 0 |", done.stdout)
            done = self.table(*[r for r in runs if "hess" not in r])
            self.assertNotEqual(done.returncode, 0)
            self.assertIn("--factorial: no run of hess", done.stderr)


class RunArchive(unittest.TestCase):
    """run_archive.py pack / check, and the readers that take a packed folder for a run folder."""

    # Actor 0's second episode (of three) was its FR episode.
    LINES = [{"learner/schedule/train_episodes": e, "learner/charts/coverage": c, "actor0/actor/episodes": a,
              "actor0/actor/fr/episodes": f} for e, c, a, f in ((10, 0.25, 1, 0), (20, 0.5, 2, 1), (30, 0.625, 3, 1))]
    SCRIPT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "run_archive.py")

    def setUp(self):
        self.tmp = tempfile.TemporaryDirectory()
        self.addCleanup(self.tmp.cleanup)
        self.runs = os.path.join(self.tmp.name, "runs")
        self.out = os.path.join(self.tmp.name, "archive")

    def run_dir(self, name, lines, extra=True, config=True):
        path = os.path.join(self.runs, name)
        os.makedirs(path)
        with open(os.path.join(path, "metrics.jsonl"), "w") as out:
            out.writelines(json.dumps(line) + "\n" for line in lines)
        if config:
            with open(os.path.join(path, "config.resolved.toml"), "w") as out:
                out.write("seed = 0\n")
        if extra:
            for name in ("eval.jsonl", "launches.jsonl"):
                with open(os.path.join(path, name), "w") as out:
                    out.write('{"index": 1}\n')
        return path

    def call(self, *args):
        return subprocess.run([sys.executable, self.SCRIPT, *args], capture_output=True, text=True)

    def test_pack_keeps_what_the_readers_need_and_check_finds_the_first_difference(self):
        asi = self.run_dir("asi_s0", self.LINES)
        hess = self.run_dir("hess_s0", self.LINES[:2], extra=False)
        done = self.call("pack", "--out", self.out, asi, hess)
        self.assertEqual(done.returncode, 0, done.stderr)
        self.assertIn("asi_s0: 3 lines, to episode 30", done.stdout)
        packed = os.path.join(self.out, "asi_s0")
        self.assertEqual(sorted(os.listdir(packed)), ["archive.json", "config.resolved.toml", "eval.jsonl",
                                                      "launches.jsonl", "metrics.jsonl.gz"])
        self.assertEqual(sorted(os.listdir(os.path.join(self.out, "hess_s0"))),
                         ["archive.json", "config.resolved.toml", "metrics.jsonl.gz"])
        with open(os.path.join(asi, "metrics.jsonl"), "rb") as handle:
            original = handle.read()
        with gzip.open(os.path.join(packed, "metrics.jsonl.gz"), "rb") as handle:
            self.assertEqual(handle.read(), original)
        with open(os.path.join(packed, "archive.json")) as handle:
            manifest = json.load(handle)
        self.assertEqual(manifest["files"]["metrics.jsonl"]["lines"], 3)
        self.assertEqual(manifest["files"]["metrics.jsonl"]["bytes"], len(original))
        self.assertEqual(manifest["train_episodes"], 30)
        # Packing again gives the same bytes (no time stamp in the gzip header).
        with open(os.path.join(packed, "metrics.jsonl.gz"), "rb") as handle:
            first = handle.read()
        self.assertEqual(self.call("pack", "--out", self.out, asi).returncode, 0)
        with open(os.path.join(packed, "metrics.jsonl.gz"), "rb") as handle:
            self.assertEqual(handle.read(), first)
        # The readers take the packed folder for the run folder.
        self.assertEqual(list(fr_outcomes.records(os.path.join(packed, "metrics.jsonl"))), self.LINES)
        self.assertEqual(store_reach.fr_episode_numbers(os.path.join(packed, "metrics.jsonl")), {2})
        table = os.path.join(os.path.dirname(self.SCRIPT), "arm_table.py")
        from_runs, from_archive = (
            subprocess.run([sys.executable, table, "--at", "20,30", os.path.join(root, "asi_s0")],
                           capture_output=True, text=True, check=True).stdout
            for root in (self.runs, self.out))
        self.assertIn("| asi (seeds 0) | **0.500** (0.500) | **0.625** (0.625) |", from_archive)
        self.assertEqual(from_runs, from_archive)
        # check: the same run, a rerun stopped early, a rerun that parts at line 2.
        done = self.call("check", self.out, asi)
        self.assertEqual((done.returncode, done.stdout), (0, "asi_s0: same (3 lines)\n"))
        short = os.path.join(self.tmp.name, "rerun", "asi_s0")
        os.makedirs(short)
        with open(os.path.join(short, "metrics.jsonl"), "w") as out:
            out.writelines(json.dumps(line) + "\n" for line in self.LINES[:2])
        done = self.call("check", self.out, short)
        self.assertEqual((done.returncode, done.stdout),
                         (0, "asi_s0: same over the first 2 lines (the archive goes on)\n"))
        parted = [dict(self.LINES[0]), dict(self.LINES[1], **{"learner/charts/coverage": 0.4375})]
        with open(os.path.join(short, "metrics.jsonl"), "w") as out:
            out.writelines(json.dumps(line) + "\n" for line in parted)
        done = self.call("check", self.out, short, os.path.join(self.runs, "none_s0"))
        self.assertEqual(done.returncode, 1)
        self.assertEqual(done.stdout.splitlines(), ["asi_s0: line 2 differs: learner/charts/coverage",
                                                    f"none_s0: not in {self.out}"])

    def test_pack_refuses_what_is_not_a_run_and_writes_nothing(self):
        good = self.run_dir("asi_s0", self.LINES)
        bad = self.run_dir("hess_s0", self.LINES, config=False)
        done = self.call("pack", "--out", self.out, good, bad)
        self.assertNotEqual(done.returncode, 0)
        self.assertIn("hess_s0: not a run folder (no config.resolved.toml)", done.stderr)
        self.assertFalse(os.path.exists(self.out))
        other = os.path.join(self.tmp.name, "other", "asi_s0")
        shutil.copytree(good, other)
        done = self.call("pack", "--out", self.out, good, other)
        self.assertIn("two run folders are named asi_s0", done.stderr)
        self.assertFalse(os.path.exists(self.out))
        # A plain metrics.jsonl is read before a packed one beside it.
        with open(os.path.join(good, "metrics.jsonl.gz"), "wb") as handle:
            handle.write(b"not gzip")
        self.assertEqual(len(list(fr_outcomes.records(os.path.join(good, "metrics.jsonl")))), 3)


class EvalTable(unittest.TestCase):
    """eval_table.py: first successes, window counts and means, coverage at episodes."""

    def run_dir(self, name, evals, metrics, packed=False):
        path = os.path.join(self.tmp.name, name)
        os.makedirs(path)
        with open(os.path.join(path, "eval.jsonl"), "w") as out:
            for episode, rate, distance in evals:
                out.write(json.dumps({"train_episodes": episode, "success_rate": rate,
                                      "mean_final_path_distance": distance}) + "\n")
        lines = "".join(json.dumps(m) + "\n" for m in metrics)
        if packed:
            with gzip.open(os.path.join(path, "metrics.jsonl.gz"), "wt") as out:
                out.write(lines)
        else:
            with open(os.path.join(path, "metrics.jsonl"), "w") as out:
                out.write(lines)
        return path

    def setUp(self):
        self.tmp = tempfile.TemporaryDirectory()
        self.addCleanup(self.tmp.cleanup)
        # Episodes of 500 steps; a metrics line every 25 episodes, the first one with no coverage.
        self.metrics = [{"learner/schedule/train_episodes": e, "learner/ingest/env_steps": 500.0 * e + 7,
                         **({"learner/charts/coverage": e / 1000} if e else {})}
                        for e in range(0, 401, 25)]
        # Episode 200 evaluated twice (a resume): the newest line counts.
        self.evals = [(50, 0.0, 20.0), (100, 0.0, 18.0), (150, 0.2, 9.0), (200, 0.0, 12.0),
                      (200, 0.5, 4.0), (250, 1.0, 1.0), (300, 0.0, 11.0)]

    def test_figures_against_hand_computed_values(self):
        run = self.run_dir("a", self.evals, self.metrics)
        s = eval_table.summary(run, (150, 300), [100, 130, 400, 500])
        self.assertEqual(s["evaluations"], 6)
        self.assertEqual(s["last_episode"], 300)
        self.assertEqual((s["first_success"], s["first_success_rate"]), (150, 0.2))
        self.assertEqual(s["first_success_env_steps"], 75007)
        self.assertEqual(s["first_full"], 250)
        self.assertEqual(s["window_evaluations"], 4)
        self.assertEqual(s["window_successes"], [0.2, 0.5, 1.0])
        self.assertAlmostEqual(s["window_mean_success"], (0.2 + 0.5 + 1.0 + 0.0) / 4)
        self.assertAlmostEqual(s["window_mean_path_distance"], (9.0 + 4.0 + 1.0 + 11.0) / 4)
        # The first line reaching 130 is episode 150's; nothing reaches 500.
        self.assertEqual(s["coverage"], {100: 0.1, 130: 0.15, 400: 0.4})
        # Without a window every evaluation counts.
        s = eval_table.summary(run)
        self.assertEqual((s["window"], s["window_evaluations"]), ((50, 300), 6))

    def test_the_table_has_a_column_per_run_and_reads_packed_metrics(self):
        a = self.run_dir("asi", self.evals, self.metrics)
        never = self.run_dir("no-si", [(50, 0.0, 20.0), (100, 0.0, 19.0)], self.metrics, packed=True)
        script = os.path.join(os.path.dirname(os.path.abspath(__file__)), "eval_table.py")
        done = subprocess.run([sys.executable, script, "--window", "100-250", "--at", "100,200", a, never],
                              capture_output=True, text=True)
        self.assertEqual(done.returncode, 0, done.stderr)
        lines = done.stdout.splitlines()
        self.assertEqual(lines[0], "| | asi | no-si |")
        self.assertIn("| first test success: episode (env steps), rate | 150 (75,007), 0.2 | none |", lines)
        self.assertIn("| evaluations of 100–250 with success (of) | 3 of 4 (0.2, 0.5, 1.0) | 0 of 1 |", lines)
        self.assertIn("| mean test success, 100–250 | 0.425 | 0.000 |", lines)
        self.assertIn("| coverage at 100 / 200 episodes | 0.100 / 0.200 | 0.100 / 0.200 |", lines)
        # A folder without evaluations, and a reversed window, are refused.
        empty = os.path.join(self.tmp.name, "empty")
        os.makedirs(empty)
        for args in (["--window", "9-1", a], [a, empty]):
            done = subprocess.run([sys.executable, script, *args], capture_output=True, text=True)
            self.assertNotEqual(done.returncode, 0, args)
        self.assertIn("no eval.jsonl", done.stderr)


if __name__ == "__main__":
    unittest.main()
