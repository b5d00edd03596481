"""Does a continuous controller reach the continuous env's reference values?

    python benchmarks/reference_rollout.py --map benchmarks/maps/hall.toml \
        --dag "M>A>G" --slack 0 --resolutions 4 8 --deltas 0.01 0.2

The reference (`tpo solve --dynamics continuous`) is a finite lattice model, so
its values could be ones no policy in the env itself attains. This acts it out:
the env (noise-free, from the map's start, run as long as a learned policy's
judgement runs it: :func:`tpo.algo.evaluate.noise_free`) with, at every true position, each
reference action looked one step ahead and the next position's values ``V*_i``
read off the lattice by its bilinear weights; along the chain DAG's order every
objective but the last keeps the actions within its edge's slack (LAR's ``eta``)
plus ``delta`` of its best, the last takes its best. It prints the rollout's
discounted returns and its path's category beside the reference policy's values,
per resolution and delta.
Chains only (a fan's admissible sets are not a lexicographic order).
"""

from __future__ import annotations

import argparse
import itertools

import jax
import jax.numpy as jnp
import numpy as np

from tpo.algo.evaluate import noise_free
from tpo.envs import OBJECTIVES, ContinuousNav, load_map
from tpo.envs.continuous import ContinuousState
from tpo.envs.continuous_model import ContinuousModel, continuous_model, path_category
from tpo.graph import ObjectiveGraph
from tpo.tabular import solve_lar


def rollout(env: ContinuousNav, ref: ContinuousModel, values: np.ndarray, order: list[int],
            allowance: list[float], gamma: float) -> tuple[np.ndarray, np.ndarray]:
    """Discounted returns ``[3]`` and positions ``[T + 1, 2]`` of the lookahead
    controller on ``env`` (noise-free); ``values [k, S]`` are the chain's ``V*`` in
    ``order``, ``allowance [k - 1]`` what each but the last may give up at a step."""
    params = env.params
    actions = jnp.asarray(ref.actions)

    @jax.jit
    def look(pos):
        state = ContinuousState(pos=pos, time=jnp.zeros((), jnp.int32))
        _, nxt, reward, term, _ = jax.vmap(
            lambda a: ContinuousNav.step_env(jax.random.key(0), state, a, params))(actions)
        return nxt.pos, reward, term

    pos = env.reset(jax.random.key(0), params)[1].pos
    returns, discount, path = np.zeros(len(OBJECTIVES)), 1.0, [np.asarray(pos)]
    for _ in range(int(params.max_steps)):
        nxt, reward, term = map(np.asarray, look(pos))
        succ, prob = ref.around(nxt)
        ahead = np.where(term[None], 0.0, (values[:, succ] * prob[None]).sum(-1))  # [k, A]
        q = reward[:, order].T + gamma * ahead
        keep = np.ones(len(actions), bool)
        for row, give in zip(q, [*allowance, 1e-9], strict=True):
            keep &= row >= row[keep].max() - give
        a = int(np.argmax(keep))
        returns += discount * reward[a]
        discount *= gamma
        pos = jnp.asarray(nxt[a])
        path.append(nxt[a])
        if term[a]:
            break
    return returns, np.array(path)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--map", default="home")
    p.add_argument("--dag", default="M>A>G")
    p.add_argument("--slack", type=float, nargs="+", default=[0.0])
    p.add_argument("--action", choices=("velocity", "heading"), default="velocity")
    p.add_argument("--resolutions", type=int, nargs="+", default=[4, 8])
    p.add_argument("--deltas", type=float, nargs="+", default=[0.01, 0.2])
    p.add_argument("--gamma", type=float, default=0.99)
    args = p.parse_args()
    env = ContinuousNav(load_map(args.map), action=args.action)
    graph = ObjectiveGraph.parse(args.dag, args.slack, objectives=OBJECTIVES, gamma=args.gamma)
    chain = list(graph.order)
    if any(len(graph.ancestors(v)) != i for i, v in enumerate(chain)):
        raise SystemExit(f"{args.dag}: a chain DAG is needed")
    order = [OBJECTIVES.index(v) for v in chain]
    etas = {(e.parent, e.child): e.slack for e in graph.edges}
    slacks = [etas[pair] for pair in itertools.pairwise(chain)]
    for n in args.resolutions:
        ref = continuous_model(env, args.gamma, resolution=n)
        sol = solve_lar(ref.model, graph)
        values = np.stack([sol.values[v] for v in chain])
        lar = sol.start_policy_values()
        print(f"{n}x{n} lattice: reference " + ", ".join(f"{v} {lar[v]:.2f}" for v in OBJECTIVES)
              + f"; path {ref.category(sol.policy)}")
        for delta in args.deltas:
            returns, path = rollout(noise_free(env, args.gamma), ref, values, order,
                                    [eta + delta for eta in slacks], args.gamma)
            print(f"  rollout, delta {delta:g}: "
                  + ", ".join(f"{v} {r:.2f}" for v, r in zip(OBJECTIVES, returns, strict=True))
                  + f" in {len(path) - 1} steps; path {path_category(env.navmap, path)}")


if __name__ == "__main__":
    main()
