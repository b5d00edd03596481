"""Time per unit and per run of a sweep unit (one compiled program of slacks x seeds)
against its size, on one XLA thread (a local or Ray worker): docs/scaling.md.

    XLA_FLAGS="--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1" \
        python benchmarks/bench_units.py [--steps 100000] [--sizes 1,2,4,8] [--repeats 3]

For each number of slack values S (x 5 seeds, the reproduction's panel (a) on
`home`), a fresh unit is compiled and trained ``steps`` env steps per run; printed:
the first chunk (compile + 32 updates), the rest per run per million steps, medians
over ``repeats``. Run it alone on an idle machine.
"""

from __future__ import annotations

import argparse
import statistics
import time

from tpo.algo import TPOConfig
from tpo.envs import load_map
from tpo.envs.grid import GridNav
from tpo.experiments.sweep import run_sweep


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=100_000)
    parser.add_argument("--sizes", default="1,2,4,8")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    env = GridNav(load_map("home"), random_start=True)
    slacks = [0.0, 1.0, 2.0, 5.0, 10.0, 20.0, 50.0, 100.0]
    print(f"{'slacks':>6} {'runs':>5} {'first chunk s':>14} {'s per run per 1M steps':>23}")
    for size in map(int, args.sizes.split(",")):
        firsts, rates = [], []
        for _ in range(args.repeats):
            marks = []
            t0 = time.monotonic()
            run_sweep(env, "M>A>G", [[s, s] for s in slacks[:size]], range(5), TPOConfig(),
                      args.steps, progress=lambda done, total: marks.append(
                          (done, time.monotonic())))
            end = time.monotonic()
            (_, start), (done1, first), *_ = marks
            total = marks[-1][0]
            firsts.append(first - t0)
            rest_steps = args.steps * (total - done1) / total
            rates.append((marks[-1][1] - first) / (5 * size) / (rest_steps / 1e6))
            del end
        print(f"{size:>6} {5 * size:>5} {statistics.median(firsts):>14.1f} "
              f"{statistics.median(rates):>23.1f}", flush=True)


if __name__ == "__main__":
    main()
