"""Training time of a sweep unit (one compiled program of slacks x seeds) against its
size and its env, on one XLA thread (a local or Ray worker): docs/scaling.md and
the continuous env's cost beside the grid's (docs/reproduce.md).

    XLA_FLAGS="--xla_cpu_multi_thread_eigen=false" \\
        python benchmarks/bench_units.py [--steps 200000] [--sizes 1,2,4,8] \\
        [--envs grid,velocity,heading] [--repeats 3] [--grid-learner]

For each env and number of slack values S (x 5 seeds, the reproduction's panel
(a) `M>A>G` on `home`; grid: the grid with its default observation, grid:KIND
with observation KIND; velocity and heading: the continuous robot, with the
observation and the learner that `tpo reproduce --continuous` trains, or with
``--grid-learner`` the grid's learner), a fresh unit is compiled and trained
``steps`` env steps per run. Printed, medians over ``repeats``: the first chunk
(compile + 32 updates), then seconds per run per million env steps after it,
and that time over the first env's of the same size (measured in the same run).
Run it alone on an idle machine.
"""

from __future__ import annotations

import argparse
import statistics
import time

from tpo.algo import TPOConfig
from tpo.envs import ContinuousNav, GridNav, load_map
from tpo.experiments.paper import CONTINUOUS_OBSERVATION
from tpo.experiments.runspec import learner_defaults
from tpo.experiments.sweep import run_sweep

SLACKS = (0.0, 1.0, 2.0, 5.0, 10.0, 20.0, 50.0, 100.0)


def make_problem(kind: str, grid_learner: bool) -> tuple[GridNav | ContinuousNav, TPOConfig]:
    """The env of ``kind`` and the config the reproduction trains on it (the grid's
    with ``grid_learner``)."""
    if kind.startswith("grid"):
        observation = kind.partition(":")[2] or "auto"
        return (GridNav(load_map("home"), observation=observation, random_start=True),
                learner_defaults("grid", ""))
    env = ContinuousNav(load_map("home"), action=kind, observation=CONTINUOUS_OBSERVATION,
                        random_start=True)
    return env, learner_defaults("grid" if grid_learner else "continuous", kind)


def time_unit(env: GridNav | ContinuousNav, config: TPOConfig, size: int, steps: int
              ) -> tuple[float, float]:
    """The first chunk's seconds, and seconds per run per 1 M steps after it."""
    marks = []
    t0 = time.monotonic()
    run_sweep(env, "M>A>G", [[s, s] for s in SLACKS[:size]], range(5), config, steps,
              progress=lambda done, total: marks.append((done, total, time.monotonic())))
    (_, _, _), (first_done, total, first), *_, (_, _, last) = marks
    rest_steps = steps * (total - first_done) / total
    return first - t0, (last - first) / (5 * size) / (rest_steps / 1e6)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=200_000)
    parser.add_argument("--sizes", default="1,2,4,8")
    parser.add_argument("--envs", default="grid")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--grid-learner", action="store_true",
                        help="train the continuous envs with the grid's learner")
    args = parser.parse_args()
    kinds = args.envs.split(",")
    print(f"{'env':>21} {'slacks':>6} {'runs':>5} {'first chunk s':>14} "
          f"{'s per run per 1M steps':>23} {'/ ' + kinds[0]:>7}")
    for size in map(int, args.sizes.split(",")):
        rates = {}
        for kind in kinds:
            env, config = make_problem(kind, args.grid_learner)
            firsts, per_run = zip(*[time_unit(env, config, size, args.steps)
                                    for _ in range(args.repeats)], strict=True)
            rates[kind] = statistics.median(per_run)
            ratio = f"{rates[kind] / rates[kinds[0]]:7.2f}"
            print(f"{kind:>21} {size:>6} {5 * size:>5} {statistics.median(firsts):>14.1f} "
                  f"{rates[kind]:>23.1f} {ratio}", flush=True)


if __name__ == "__main__":
    main()
