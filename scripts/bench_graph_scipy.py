#!/usr/bin/env python3
"""scipy side of `asi bench graph`: shortest paths on the graph the Rust bench wrote.

Usage: python3 scripts/bench_graph_scipy.py DIR

DIR holds `edges.txt` (first line: number of nodes; then `a b weight` per undirected edge) and
`queries.txt` (`from to distance` per route query, distance -1 when unreachable: the Rust
answers, checked here). The script
  - times one route query the way the graph-service answers it: single-source Dijkstra from
    `from` (scipy.sparse.csgraph.dijkstra with predecessors) plus path recovery to `to`;
  - times all-pairs shortest paths (scipy.sparse.csgraph.shortest_path, method "D");
  - checks that every distance equals the Rust one;
and prints one JSON line: scipy_version, n_queries, p50_us, p99_us, all_pairs_secs,
distances_agree.

Dependencies: the script installs pinned numpy and scipy into `.venv-bench-graph` at the
repository root (git-ignored) on first use and re-runs itself there.
"""

import json
import os
import subprocess
import sys
import time
import venv
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
VENV = ROOT / ".venv-bench-graph"
NUMPY_VERSION = "2.2.6"
SCIPY_VERSION = "1.17.1"


def ensure_venv():
    """Re-executes this script in the bench venv, creating it and installing deps if needed."""
    python = VENV / "bin" / "python"
    if Path(sys.prefix).resolve() == VENV.resolve():
        return
    if not python.exists():
        venv.EnvBuilder(with_pip=True).create(VENV)
    check = f"import numpy, scipy, sys; sys.exit(not (numpy.__version__ == '{NUMPY_VERSION}' and scipy.__version__ == '{SCIPY_VERSION}'))"
    if subprocess.run([str(python), "-c", check], capture_output=True).returncode != 0:
        subprocess.run(
            [str(python), "-m", "pip", "install", "--quiet", "--disable-pip-version-check",
             f"numpy=={NUMPY_VERSION}", f"scipy=={SCIPY_VERSION}"],
            check=True, stdout=sys.stderr,
        )
    os.execv(str(python), [str(python), __file__, *sys.argv[1:]])


def load(directory):
    import numpy as np
    from scipy.sparse import csr_matrix

    with open(directory / "edges.txt") as f:
        n_nodes = int(f.readline())
        edges = np.loadtxt(f, dtype=np.int64, ndmin=2)
    if edges.size == 0:
        edges = np.zeros((0, 3), dtype=np.int64)
    rows = np.concatenate([edges[:, 0], edges[:, 1]])
    cols = np.concatenate([edges[:, 1], edges[:, 0]])
    weights = np.concatenate([edges[:, 2], edges[:, 2]]).astype(np.float64)
    graph = csr_matrix((weights, (rows, cols)), shape=(n_nodes, n_nodes))
    queries = np.loadtxt(directory / "queries.txt", dtype=np.int64, ndmin=2)
    return graph, queries


def route(graph, source, target):
    """Distance and node path source → target, as the graph-service computes a route."""
    import numpy as np
    from scipy.sparse.csgraph import dijkstra

    dist, pred = dijkstra(graph, directed=False, indices=source, return_predecessors=True)
    if not np.isfinite(dist[target]):
        return -1, []
    path = [target]
    while path[-1] != source:
        path.append(pred[path[-1]])
    path.reverse()
    return int(dist[target]), path


def main():
    ensure_venv()
    import numpy as np
    import scipy
    from scipy.sparse.csgraph import shortest_path

    directory = Path(sys.argv[1])
    graph, queries = load(directory)
    micros, agree = [], True
    for source, target, expected in queries:
        start = time.perf_counter()
        distance, _ = route(graph, int(source), int(target))
        micros.append((time.perf_counter() - start) * 1e6)
        agree &= distance == int(expected)
    start = time.perf_counter()
    shortest_path(graph, method="D", directed=False)
    all_pairs_secs = time.perf_counter() - start
    micros = np.sort(np.array(micros))
    nearest_rank = lambda q: float(micros[max(int(np.ceil(q * len(micros))), 1) - 1])
    print(json.dumps({
        "scipy_version": scipy.__version__,
        "n_queries": len(micros),
        "p50_us": nearest_rank(0.5),
        "p99_us": nearest_rank(0.99),
        "all_pairs_secs": all_pairs_secs,
        "distances_agree": bool(agree),
    }))


if __name__ == "__main__":
    main()
