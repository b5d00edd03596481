"""LAR value iteration on large grids: wall-clock time and peak memory.

    python benchmarks/bench_lar.py --sizes 100 316 1000 --repeats 3 --dags "M>A>G" "G>M>A"

An n x n open grid (4 moves, bumps at the border), goal in a corner, an avoid
band across the middle and a monitor square off the shortest path; rewards as
in docs/design.md §3; gamma 0.99. For every DAG (at --slack) and size it prints the
median time of build and solve over the repeats and the value-iteration sweeps
per objective; at the end the process's peak RSS.
"""

from __future__ import annotations

import argparse
import itertools
import resource
import statistics
import time

import numpy as np

from tpo.envs import OBJECTIVES
from tpo.graph import ObjectiveGraph
from tpo.tabular import TabularTMDP, solve_lar


def open_grid(n: int, gamma: float = 0.99) -> TabularTMDP:
    cells = np.arange(n * n)
    r, c = np.divmod(cells, n)
    moves = [(-1, 0), (1, 0), (0, -1), (0, 1)]
    succ = np.empty((n * n, 4, 1), np.int32)
    bump = np.empty((n * n, 4), bool)
    for a, (dr, dc) in enumerate(moves):
        rr, cc = r + dr, c + dc
        inside = (rr >= 0) & (rr < n) & (cc >= 0) & (cc < n)
        succ[:, a, 0] = np.where(inside, rr * n + cc, cells)
        bump[:, a] = ~inside
    goal = n * n - 1
    avoid = (r >= n // 2 - n // 10) & (r <= n // 2 + n // 10)
    monitor = (r < n // 5) & (c >= n - n // 5)
    rewards = np.empty((n * n, 4, 3))
    rewards[:, :, 0] = -1.0
    rewards[:, :, 1] = -1.0 * avoid[:, None] - bump
    rewards[:, :, 2] = monitor[:, None] * 1.0 - bump
    terminal = cells == goal
    rewards[terminal] = 0.0
    return TabularTMDP(succ, np.ones(succ.shape), rewards, OBJECTIVES,
                       gamma=gamma, start=0, terminal=terminal)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[100, 316, 1000])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--dags", nargs="+", default=["M>A>G"])
    parser.add_argument("--slack", type=float, default=0.0)
    args = parser.parse_args()
    print(f"{'dag':>10} {'states':>10} {'build s':>8} {'solve s':>8}  sweeps  V_pi(s0)")
    for dag, n in itertools.product(args.dags, args.sizes):
        graph = ObjectiveGraph.parse(dag, args.slack, objectives=OBJECTIVES)
        builds, solves = [], []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            model = open_grid(n)
            t1 = time.perf_counter()
            sol = solve_lar(model, graph, relax=True)
            t2 = time.perf_counter()
            builds.append(t1 - t0)
            solves.append(t2 - t1)
        pv = {k: round(v, 2) for k, v in sol.start_policy_values().items()}
        print(f"{dag:>10} {n * n:>10} {statistics.median(builds):8.2f} "
              f"{statistics.median(solves):8.2f}"
              f"  {sol.iterations}  {pv}", flush=True)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"peak RSS {peak:.0f} MiB")


if __name__ == "__main__":
    main()
