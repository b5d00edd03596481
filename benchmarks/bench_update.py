"""Where one grid update's time goes, and what reading the observation's one-hot
blocks by gathers saves (:class:`tpo.algo.networks.InputDense`).

    python benchmarks/bench_update.py --runs 5 --repeats 7

One PPO update of ``--runs`` seeds vmapped (the reproduction's unit is 5-20), on
``--map``'s grid in the leaf phase of ``M>A>G``, timed in three cumulative pieces:
the rollout (``collect``), then the critics' targets, then the PPO epochs. Each
piece is timed with the first layers as gathers of the one-hot blocks (the
library's networks) and as plain dense products of the whole observation (the
same parameters, the baseline), the two compiled in this process and called in
turn, ``--calls`` calls a timing; medians over ``--repeats`` timings and the
ratio gathered / dense per repeat.
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import time

import jax
import jax.numpy as jnp

from tpo.algo import TPOConfig
from tpo.algo.train import Trainer
from tpo.envs import load_map
from tpo.envs.grid import GridNav
from tpo.graph import ObjectiveGraph


def pieces(trainer: Trainer, runs: int) -> dict:
    """The three cumulative programs, compiled, and their vmapped arguments."""
    state = jax.tree.map(lambda *x: jnp.stack(x),
                         *[trainer.init(jax.random.key(s)) for s in range(runs)])
    state = state.replace(update=state.update + int(trainer.phase_start[-2]))  # the leaf
    slack = trainer.slack_array()

    def targets(s, sl):
        s, rollout, _ = trainer.collect(s, sl)
        return trainer.lagrangian_targets(s, sl, rollout, trainer.phase_of(s.update))

    funcs = {"collect": lambda s, sl: trainer.collect(s, sl), "+ targets": targets,
             "+ epochs": lambda s, sl: trainer.update(s, sl)}
    out = {}
    for name, f in funcs.items():
        f = jax.jit(jax.vmap(f, in_axes=(0, None)))
        jax.block_until_ready(f(state, slack))  # compile
        out[name] = (f, state, slack)
    return out


def timed(f, state, slack, calls: int) -> float:
    start = time.perf_counter()
    for _ in range(calls):
        out = f(state, slack)
    jax.block_until_ready(out)
    return (time.perf_counter() - start) / calls * 1000


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--map", default="home")
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--calls", type=int, default=5)
    args = parser.parse_args()
    env = GridNav(load_map(args.map), random_start=True)
    graph = ObjectiveGraph.parse("M>A>G", [5.0, 5.0], objectives=env.objectives)
    gathered = Trainer(env, graph, TPOConfig(), 10**6)
    dense = Trainer(env, graph, TPOConfig(), 10**6)
    dense.actor = dataclasses.replace(dense.actor, onehots=())
    dense.critics = dataclasses.replace(dense.critics, onehots=())
    print(f"{args.map}: observation {env.observation}, {env.obs_shape[0]} numbers, one-hot "
          f"blocks {env.observation_onehots}; {args.runs} runs x {gathered.config.batch_size} "
          f"steps an update")
    progs = {"gathered": pieces(gathered, args.runs), "dense": pieces(dense, args.runs)}
    times = {(kind, name): [] for kind in progs for name in progs[kind]}
    for _ in range(args.repeats):
        for name in progs["dense"]:
            for kind in progs:
                times[kind, name].append(timed(*progs[kind][name], args.calls))
    print(f"| piece (cumulative) | dense ms | gathered ms | ratio (median of {args.repeats}) |")
    print("|---|---:|---:|---:|")
    for name in progs["dense"]:
        d, g = times["dense", name], times["gathered", name]
        ratios = [a / b for a, b in zip(g, d, strict=True)]
        print(f"| {name} | {statistics.median(d):.1f} | {statistics.median(g):.1f} | "
              f"{statistics.median(ratios):.3f} ({min(ratios):.3f}-{max(ratios):.3f}) |")


if __name__ == "__main__":
    main()
