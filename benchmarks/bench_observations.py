"""Which grid observation does PPO learn from reliably? (issue 3's evidence)

    python benchmarks/bench_observations.py --map home --seeds 8 --steps 500000

Plain PPO (TPO with the one-objective graph) on each objective alone, for every
observation encoding, with and without random starts, over several seeds in one
vmapped run. A seed "solves" the map when the exact value of its greedy policy
from the start is within 1% (or 0.5) of the optimum. Prints solved/seeds and
the mean exact greedy value.
"""

from __future__ import annotations

import argparse
import time

import jax
import jax.numpy as jnp

from tpo.algo.config import TPOConfig
from tpo.algo.evaluate import exact_evaluation
from tpo.algo.train import Trainer
from tpo.envs import load_map
from tpo.envs.grid import OBSERVATIONS, GridNav
from tpo.graph import ObjectiveGraph
from tpo.tabular import solve_lar


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--map", default="home")
    parser.add_argument("--seeds", type=int, default=8)
    parser.add_argument("--steps", type=int, default=500_000)
    parser.add_argument("--objectives", nargs="+", default=["goal", "monitor"])
    args = parser.parse_args()
    navmap, config = load_map(args.map), TPOConfig()
    print(f"{'objective':<9} {'observation':<9} {'starts':<7} {'solved':>7} {'mean V':>8} "
          f"{'optimum':>8} {'time':>6}")
    for objective in args.objectives:
        graph = ObjectiveGraph.parse(objective)
        for kind in OBSERVATIONS:
            for random_start in (False, True):
                t0 = time.perf_counter()
                train_env = GridNav(navmap, observation=kind, random_start=random_start)
                eval_env = GridNav(navmap, observation=kind)
                trainer = Trainer(train_env, graph, config, args.steps)
                states = [trainer.init(jax.random.key(s)) for s in range(args.seeds)]
                states = jax.tree.map(lambda *x: jnp.stack(x), *states)
                states, _ = jax.jit(jax.vmap(lambda s, t=trainer: t.run(
                    s, t.slack_array(), t.num_updates)))(states)
                best = solve_lar(eval_env.tabular(config.gamma).model,
                                 graph).start_values()[objective]
                values = [exact_evaluation(
                    trainer.policy, trainer.acting(jax.tree.map(lambda x, i=i: x[i], states),
                                                   trainer.slack_array()),
                    eval_env, graph, config.gamma)["exact"]["greedy"][objective]
                    for i in range(args.seeds)]
                solved = sum(abs(v - best) <= max(0.5, 0.01 * abs(best)) for v in values)
                print(f"{objective:<9} {kind:<9} {'random' if random_start else 'fixed':<7} "
                      f"{solved:>3}/{args.seeds:<3} {sum(values) / len(values):8.2f} "
                      f"{best:8.2f} {time.perf_counter() - t0:5.0f}s", flush=True)


if __name__ == "__main__":
    main()
