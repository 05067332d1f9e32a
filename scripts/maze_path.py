#!/usr/bin/env python3
"""How far along a maze a position is, for the analysis scripts, on any maze task.

    scripts/maze_path.py TASK X,Y...      e.g. scripts/maze_path.py pointmaze-s 16,6 -1,0.5

The maze comes from `asi tasks TASK --json` (the map rows, the cell size and the start cell;
`asi` is $ASI_BIN, else target/release/asi, else target/debug/asi), or, for a run folder, from
the task named in its config.resolved.toml. A position's progress is its distance from the
start along the maze's corridors, in metres: the cells' centres joined to their neighbours one
step further from the start (breadth-first over free cells, 4-neighbour) form the centreline,
and a position counts as the point of that centreline nearest to it. The start's centre is 0
and the centre of a cell d steps from the start is d times the cell size, so the test goal of
AntMaze-U, 6 cells from the start, is at 24 m. In a straight corridor this is the position's
coordinate along it; in a corner cell a position goes to the nearer of the two half-segments.
A position in a wall or outside the grid (a torso pressed against a wall can be looked up in
it) counts in the free cell whose centre is nearest. Standard library only.

Before these were maze-generic, fr_outcomes.py, store_reach.py and fr_trace.py measured
AntMaze-U positions by a hand-written U centreline (`along_u`); it agrees with this one except
in the U's two corner cells: there a position near the cell's diagonal is nearly as close to
the half-segment in as to the one out, and the two measures can differ by up to a cell (4 m).
"""
import functools
import json
import math
import os
import subprocess
import sys
import tomllib

COVERAGE_CELL = 0.6  # metres, envs::coverage::COVERAGE_CELL_M
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


class MazePath:
    """Progress along one maze: `MazePath(description["maze"])` with the `maze` object of
    `asi tasks NAME --json`."""

    def __init__(self, maze):
        self.rows = maze["rows"]
        self.size = float(maze["cell_size_m"])
        self.robot = tuple(maze["robot_cell"])
        self.goal_box = tuple(tuple(float(v) for v in corner) for corner in maze["goal_box"])
        self.free = {
            (i, j)
            for i, row in enumerate(self.rows)
            for j, char in enumerate(row)
            if char != "#"
        }
        if self.robot not in self.free:
            raise ValueError(f"the robot cell {self.robot} is not free in {self.rows}")
        self.steps = self._bfs()
        # Each free cell's centreline pieces: (start xy, end xy, progress at the start), the
        # half-segments from its centre toward each neighbour one step nearer the start or
        # further from it, both oriented in the direction of travel.
        self.pieces = {}
        for cell, d in self.steps.items():
            centre = self.centre(cell)
            pieces = []
            for other in self.neighbours(cell):
                mid = tuple((a + b) / 2 for a, b in zip(centre, self.centre(other)))
                if self.steps[other] == d - 1:
                    pieces.append((mid, centre, (d - 0.5) * self.size))
                elif self.steps[other] == d + 1:
                    pieces.append((centre, mid, d * self.size))
            self.pieces[cell] = pieces

    def centre(self, cell):
        """World xy of a cell's centre: the start cell's centre is the origin, y grows with
        the row (as `Maze::cell_center`)."""
        return ((cell[1] - self.robot[1]) * self.size, (cell[0] - self.robot[0]) * self.size)

    def cell_of(self, x, y):
        """The cell of (x, y) by the environment's lookup, ceil(coordinate / size - 0.5)."""
        return (
            self.robot[0] + math.ceil(y / self.size - 0.5),
            self.robot[1] + math.ceil(x / self.size - 0.5),
        )

    def neighbours(self, cell):
        i, j = cell
        return [c for c in ((i - 1, j), (i + 1, j), (i, j - 1), (i, j + 1)) if c in self.free]

    def _bfs(self):
        steps, frontier = {self.robot: 0}, [self.robot]
        while frontier:
            nxt = []
            for cell in frontier:
                for other in self.neighbours(cell):
                    if other not in steps:
                        steps[other] = steps[cell] + 1
                        nxt.append(other)
            frontier = nxt
        return steps

    def progress(self, x, y):
        """Metres along the maze from the start to the centreline point nearest (x, y)."""
        cell = self.cell_of(x, y)
        if cell not in self.steps:
            cell = min(self.steps, key=lambda c: math.dist(self.centre(c), (x, y)))
        pieces = self.pieces[cell]
        if not pieces:  # a one-cell maze
            return 0.0
        best = None
        for start, end, at in pieces:
            dx, dy = end[0] - start[0], end[1] - start[1]
            length_sq = dx * dx + dy * dy
            t = max(0.0, min(1.0, ((x - start[0]) * dx + (y - start[1]) * dy) / length_sq))
            gap = math.dist((start[0] + t * dx, start[1] + t * dy), (x, y))
            if best is None or gap < best[0]:
                best = (gap, at + t * math.sqrt(length_sq))
        return best[1]


    def coverage_cell(self, x, y, size=COVERAGE_CELL):
        """The cell (ix, iy) of the coverage grid (`charts/coverage`, docs/METRICS.md: `size`
        cells over the goal box from its low corner, the far edge in the last cell) that holds
        (x, y), when its centre is in a free maze cell; None when it is not, or (x, y) is
        outside the goal box."""
        index = []
        for v, low, high in zip((x, y), self.goal_box[0], self.goal_box[1]):
            if not low <= v <= high:
                return None
            # ceil with a tolerance: 12 / 0.6 is 20.000000000000004 in binary floating point
            n = max(1, math.ceil((high - low) / size - 1e-6))
            index.append(min(math.floor((v - low) / size), n - 1))
        centre = [low + (i + 0.5) * size for i, low in zip(index, self.goal_box[0])]
        if self.cell_of(*centre) not in self.free:
            return None
        return tuple(index)


def asi_binary():
    """$ASI_BIN, else the release build, else the debug build of this checkout."""
    if os.environ.get("ASI_BIN"):
        return os.environ["ASI_BIN"]
    for profile in ("release", "debug"):
        path = os.path.join(ROOT, "target", profile, "asi")
        if os.access(path, os.X_OK):
            return path
    sys.exit("no asi binary: build it (cargo build --release) or set ASI_BIN")


@functools.lru_cache(maxsize=None)
def for_task(task):
    """The MazePath of a registered maze task (one `asi tasks` call per task)."""
    result = subprocess.run(
        [asi_binary(), "tasks", task, "--json"], capture_output=True, text=True, check=False
    )
    if result.returncode != 0:
        sys.exit(f"asi tasks {task} --json failed: {result.stderr.strip()}")
    maze = json.loads(result.stdout)["maze"]
    if maze is None:
        sys.exit(f"task {task} has no maze, so positions have no progress along one")
    return MazePath(maze)


def task_of_run(run_dir):
    """The task named in a run folder's config.resolved.toml (`[env] task`)."""
    path = os.path.join(run_dir, "config.resolved.toml")
    try:
        with open(path, "rb") as handle:
            return tomllib.load(handle)["env"]["task"]
    except (OSError, KeyError, tomllib.TOMLDecodeError) as err:
        sys.exit(f"{path}: cannot read the run's task ({err})")


def for_run(run_dir):
    """The MazePath of the task a run folder trained on."""
    return for_task(task_of_run(run_dir))


def main(args):
    if len(args) < 2:
        print(__doc__, file=sys.stderr)
        return 2
    path = for_task(args[0])
    for point in args[1:]:
        try:
            x, y = (float(v) for v in point.split(","))
        except ValueError:
            sys.exit(f"'{point}' is not X,Y")
        print(f"({x}, {y}): {path.progress(x, y):.2f} m")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
