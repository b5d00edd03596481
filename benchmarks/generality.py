"""Does TPO keep its priorities on problems nobody tuned it for? Generated TMDPs,
trained as a user would (the defaults a user gets, a given budget) and judged
exactly on their models.

    python benchmarks/generality.py --problems 100 --steps 1000000
    python benchmarks/generality.py --problems 4 --steps 100000 --json out.json
    python benchmarks/generality.py --problems 0 --mo-gym host   # MO-Gymnasium's envs

Problem ``i`` is ``random_tmdp`` with seed ``i`` and a shape drawn from seed
``i`` as well (states 10-200, actions 2-8, objectives 2-4, chain, fan or DAG,
deterministic or stochastic, dense or sparse, one-hot or embedded
observations), so the list is fixed by the code. Each learned policy gets the
three verdicts of ``tpo.tabular.Judge``; a failure is broken down as an
ancestor below its floor, the leaf below its optimum, or both. Beside each
problem, plain PPO's reach of each objective alone at the same budget (with
``--ppo``): ``(v - v_uniform) / (v* - v_uniform)`` of its exact greedy value,
which separates what PPO cannot reach at all (exploration) from what TPO's
constraints lose.

With ``--mo-gym host`` (or ``jax``), MO-Gymnasium's finite envs
(:data:`MO_GYM`: each env's DAGs at slacks of 0, 10 % and 50 % of the parent's
value range at the start) are trained on the env itself stepped on the host, as
a user would (or on its stepped model served as a JAX env), and judged on the
env's stepped model (``tpo.envs.stepped_model``).
"""

from __future__ import annotations

import argparse
import functools
import json
import time

import numpy as np

from tpo.algo import TPO
from tpo.envs.random_tmdp import random_tmdp
from tpo.envs.stepped_model import mo_gym_model
from tpo.graph import ObjectiveGraph
from tpo.tabular import Judge, evaluate_policy, solve_lar
from tpo.tabular.judge import value_ranges


def shape(i: int) -> dict:
    """Problem ``i``'s generator arguments (drawn from seed ``i``)."""
    rng = np.random.default_rng([i, 59])
    return {"states": int(rng.integers(10, 201)), "actions": int(rng.integers(2, 9)),
            "objectives": int(rng.integers(2, 5)),
            "dag": str(rng.choice(["chain", "fan", "dag"])),
            "stochastic": bool(rng.uniform() < 0.5), "sparse": bool(rng.uniform() < 0.5),
            "observation": str(rng.choice(["onehot", "embedding"]))}


#: MO-Gymnasium's finite envs and the DAGs of their cases.
MO_GYM = {
    "deep-sea-treasure-v0": ("treasure>time", "time>treasure"),
    "deep-sea-treasure-concave-v0": ("treasure>time", "time>treasure"),
    "resource-gathering-v0": ("gem>gold>enemy", "enemy>gold>gem", "enemy>gem, gold>gem"),
    "breakable-bottles-v0": ("bottles>time>impact", "impact>bottles>time",
                             "impact>time, bottles>time"),
    "fruit-tree-v0": ("nutrient1>nutrient2>nutrient3", "nutrient4>nutrient5",
                      "nutrient1>nutrient6, nutrient2>nutrient6"),
}
SHARES = (0.0, 0.1, 0.5)  # of the parent's value range at the start


def greedy(model: TPO, problem) -> np.ndarray:
    """The learned greedy action of every state of the problem's model."""
    obs = problem.observations
    return np.asarray(model.predict(obs)).astype(np.int64)


def reach(problem, steps: int, seed: int, env=None) -> dict[str, float]:
    """Plain PPO's reach of each objective alone on ``env`` (by default the problem's
    JAX env with exploring starts): ``(v - v_uniform) / (v* - v_uniform)``."""
    m = problem.model
    env = problem.env(random_start=True) if env is None else env
    uniform = evaluate_policy(m, np.full((m.n_states, m.n_actions), 1 / m.n_actions))
    out = {}
    for i, name in enumerate(m.objectives):
        alone = ObjectiveGraph((name,))
        best = solve_lar(m, alone).start_values()[name]
        learner = TPO(env, alone, objectives=m.objectives, seed=seed).learn(steps)
        value = evaluate_policy(m, greedy(learner, problem))[m.start, i]
        base = uniform[m.start, i]
        out[name] = float((value - base) / (best - base)) if best > base else 1.0
    return out


def verdict_row(problem, model: TPO, graph: ObjectiveGraph) -> dict:
    """The three verdicts of a learned policy on its problem's model, and its failure."""
    lar = solve_lar(problem.model, graph, relax=True)
    judge = Judge(lar)
    verdict = judge(greedy(model, problem))
    below_floor = [w for w, f in verdict.floors.items()
                   if verdict.values[w] < f - judge.tolerance(w, f)]
    leaf_short = verdict.values[graph.leaf] < verdict.optimum - judge.tolerance(
        graph.leaf, verdict.optimum)
    failure = ("" if verdict.lar_correct else "both" if below_floor and leaf_short
               else "ancestor below floor" if below_floor else "leaf below optimum")
    return {"feasible": verdict.feasible, "lar_correct": verdict.lar_correct,
            "strict": verdict.strict, "same_values": verdict.same_values,
            "failure": failure, "below_floor": below_floor,
            "values": {w: round(float(x), 4) for w, x in verdict.values.items()},
            "floors": {w: round(float(x), 4) for w, x in verdict.floors.items()},
            "optimum": round(float(verdict.optimum), 4)}


def case(i: int, steps: int, population: int, ppo: bool) -> dict:
    problem = random_tmdp(i, **shape(i))
    start = time.perf_counter()
    model = TPO(problem.env(random_start=True), problem.graph, seed=i,
                population=population).learn(steps)
    row = {"problem": i, **shape(i), **verdict_row(problem, model, problem.graph),
           "seconds": round(time.perf_counter() - start, 1)}
    if ppo:
        row["ppo_reach"] = reach(problem, steps, i)
    return row


def mo_gym_cases() -> list[tuple[str, ObjectiveGraph, float]]:
    """``(env id, DAG with its slacks, share)`` of every MO-Gymnasium case: each edge's
    global slack is the share of its parent's value range (local slack: times 1 - gamma)."""
    cases = []
    for env_id, dags in MO_GYM.items():
        m = mo_gym_model(env_id).model
        ranges = value_ranges(m)
        for dag in dags:
            graph = ObjectiveGraph.parse(dag, 0.0).bind(m.objectives)
            for share in SHARES:
                slacks = [(1 - m.gamma) * share * ranges[e.parent] for e in graph.edges]
                cases.append((env_id, graph.with_slack(slacks), share))
    return cases


def mo_gym_case(env_id: str, graph: ObjectiveGraph, share: float, steps: int,
                population: int, path: str, seed: int, ppo: bool) -> dict:
    stepped = mo_gym_model(env_id)
    env = f"mo-gymnasium:{env_id}" if path == "host" else stepped.env()
    start = time.perf_counter()
    model = TPO(env, graph, objectives=stepped.model.objectives, seed=seed,
                population=population).learn(steps)
    row = {"env": env_id, "dag": graph.spec, "share": share, "path": path,
           **verdict_row(stepped, model, graph),
           "seconds": round(time.perf_counter() - start, 1)}
    if ppo:
        row["ppo_reach"] = mo_gym_reach(env_id, steps, path)
    return row


@functools.cache
def mo_gym_reach(env_id: str, steps: int, path: str) -> dict[str, float]:
    """Plain PPO's reach of each objective of an MO-Gymnasium env (seed 0), once per env."""
    stepped = mo_gym_model(env_id)
    return reach(stepped, steps, 0, f"mo-gymnasium:{env_id}" if path == "host" else stepped.env())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--problems", type=int, default=100)
    parser.add_argument("--first", type=int, default=0, help="the first problem's index")
    parser.add_argument("--steps", type=int, default=1_000_000)
    parser.add_argument("--population", type=int, default=4)
    parser.add_argument("--ppo", action="store_true", help="plain PPO's reach beside each")
    parser.add_argument("--mo-gym", choices=("host", "jax"),
                        help="also MO-Gymnasium's cases, on the env (host) or its model (jax)")
    parser.add_argument("--json", help="write the rows to this file")
    args = parser.parse_args()
    rows = []
    for i in range(args.first, args.first + args.problems):
        rows.append(case(i, args.steps, args.population, args.ppo))
        print(json.dumps(rows[-1]), flush=True)
    for j, (env_id, graph, share) in enumerate(mo_gym_cases() if args.mo_gym else ()):
        rows.append(mo_gym_case(env_id, graph, share, args.steps, args.population,
                                args.mo_gym, j, args.ppo))
        print(json.dumps(rows[-1]), flush=True)
    n = len(rows)
    for verdict in ("lar_correct", "strict", "same_values"):
        print(f"{verdict}: {sum(r[verdict] for r in rows)}/{n}")
    for kind in ("ancestor below floor", "leaf below optimum", "both"):
        print(f"  failures, {kind}: {sum(r['failure'] == kind for r in rows)}")
    if args.json:
        with open(args.json, "x") as f:  # never replaces a file
            json.dump(rows, f, indent=1)


if __name__ == "__main__":
    main()
