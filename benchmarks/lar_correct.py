"""How often the learner is LAR-correct: problems x seeds on a map, judged exactly.

    python benchmarks/lar_correct.py --map small --steps 600000 --seeds 4
    python benchmarks/lar_correct.py --map home --problems "M>A>G:5,5" "G>M>A:5,0"
    python benchmarks/lar_correct.py --set "constraint='penalty'"  # the paper's form
    python benchmarks/lar_correct.py --map held.toml --population 4 --seeds 1  # as tpo train

Each problem (``DAG:slack``) trains all its seeds as one vmapped sweep
(:func:`tpo.experiments.sweep.run_sweep`); with ``--population M`` every seed is
a model of M learners (:class:`tpo.algo.TPO`, as ``tpo train`` trains), trained
one seed after another. Each run is judged by
:class:`tpo.tabular.Judge` (docs/design.md §6). Prints one line per problem
(counts of LAR-correct, strict and same-values seeds, and the mean learned
values beside LAR's) and the totals, then one JSON line with everything.
"""

from __future__ import annotations

import argparse
import json
import time
from types import SimpleNamespace

import numpy as np

from tpo.algo import TPO, TPOConfig
from tpo.envs import load_map
from tpo.envs.grid import OBSERVATIONS, GridNav
from tpo.experiments.sweep import run_sweep

# The four paper DAGs at slack 0 and 100, and Figure 3's M>A>G (100, 0).
PROBLEMS = ("M>A>G:0,0", "M>A>G:100,100", "A>M>G:0,0", "A>M>G:0,100", "G>M>A:0,0",
            "G>M>A:100,0", "A>G, M>G:0,0", "A>G, M>G:100,100", "M>A>G:100,0")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--map", default="small")
    parser.add_argument("--problems", nargs="+", default=list(PROBLEMS), metavar="DAG:SLACK")
    parser.add_argument("--seeds", type=int, default=4)
    parser.add_argument("--first-seed", type=int, default=0, help="seeds first-seed, ...")
    parser.add_argument("--observation", default="auto", choices=("auto", *OBSERVATIONS))
    parser.add_argument("--steps", type=int, default=600_000)
    parser.add_argument("--population", type=int, default=1,
                        help="learners per run (tpo train's default: 4)")
    parser.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE",
                        help="TPOConfig fields, as TOML values (constraint='penalty')")
    args = parser.parse_args()
    config = TPOConfig.from_toml("\n".join(args.set))
    env = GridNav(load_map(args.map), random_start=True, observation=args.observation)
    totals = dict.fromkeys(("lar_correct", "strict", "same_values", "runs"), 0)
    rows = []
    print(f"{'problem':<22} {'correct':>8} {'strict':>7} {'same':>5}  learned (mean) / LAR")
    for problem in args.problems:
        dag, _, slack = problem.rpartition(":")
        t0 = time.perf_counter()
        slacks = [float(v) for v in slack.split(",")]
        seeds = list(range(args.first_seed, args.first_seed + args.seeds))
        result = (run_sweep(env, dag, [slacks], seeds, config, args.steps)
                  if args.population == 1 else population_runs(env, dag, slacks, args, config))
        counts = {k: int(getattr(result, k)[0].sum()) for k in
                  ("lar_correct", "strict", "same_values")}
        for k, v in counts.items():
            totals[k] += v
        totals["runs"] += args.seeds
        learned = result.exact[0].mean(axis=0)
        pairs = " ".join(f"{n[0]} {v:.1f}/{w:.1f}" for n, v, w in
                         zip(result.objectives, learned, result.lar[0], strict=True))
        print(f"{problem:<22} {counts['lar_correct']:>5}/{args.seeds} "
              f"{counts['strict']:>4}/{args.seeds} {counts['same_values']:>2}/{args.seeds}  "
              f"{pairs}  {'' if result.feasible[0] else '(infeasible: relaxed) '}"
              f"{time.perf_counter() - t0:.0f}s", flush=True)
        rows.append({"problem": problem, **counts, "feasible": bool(result.feasible[0]),
                     "exact": result.exact[0].tolist(), "lar": result.lar[0].tolist()})
    n = totals["runs"]
    print(f"{'total':<22} {totals['lar_correct']:>5}/{n} {totals['strict']:>4}/{n} "
          f"{totals['same_values']:>2}/{n}")
    print(json.dumps({"map": args.map, "observation": args.observation, "steps": args.steps,
                      "population": args.population,
                      "seeds": args.seeds, "first_seed": args.first_seed,
                      "config": config.to_dict(),
                      "totals": totals, "problems": rows}))


def population_runs(env: GridNav, dag: str, slack: list[float], args: argparse.Namespace,
                    config: TPOConfig) -> SimpleNamespace:
    """Every seed a :class:`TPO` model of ``args.population`` learners, judged exactly;
    the fields of a one-slack :class:`tpo.experiments.sweep.SweepResult` this
    script reads."""
    verdicts, exact = [], []
    for seed in range(args.first_seed, args.first_seed + args.seeds):
        model = TPO(env, dag, slack, config, seed, population=args.population)
        result = model.learn(args.steps).evaluate(episodes=1)
        verdicts.append([result[k] for k in ("lar_correct", "strict", "same_values")])
        exact.append(list(result["exact"]["greedy"].values()))
        lar = result["lar"]
    v = np.array([verdicts])
    return SimpleNamespace(lar_correct=v[..., 0], strict=v[..., 1], same_values=v[..., 2],
                           exact=np.array([exact]),
                           lar=np.array([list(lar["policy_values"].values())]),
                           feasible=[lar["feasible"]], objectives=env.objectives)


if __name__ == "__main__":
    main()
