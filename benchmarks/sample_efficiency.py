"""Sample efficiency: how many steps each family of problems needs to be LAR-correct.

    python benchmarks/sample_efficiency.py                       # both forms, home
    python benchmarks/sample_efficiency.py --forms penalty --budgets 500000 1000000

Every problem (``DAG:slack``) is trained at every budget in ``--budgets`` (each a
whole run: the phases share the budget, as in ``tpo train --steps``), its seeds
vmapped in one sweep, and judged exactly (docs/design.md §7). A seed's *steps to
LAR-correct* is the smallest budget from which on its run is LAR-correct at every
larger budget measured (``>`` the largest when it never is). Prints, per form and
problem, the LAR-correct counts at each budget and the median over seeds of the
steps to LAR-correct, then one JSON line with everything.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from tpo.algo import TPOConfig
from tpo.envs import load_map
from tpo.envs.grid import GridNav
from tpo.experiments.sweep import run_sweep

# A problem per family of docs/notes/tpo-learning.md: exploring under a constraint
# (A>M>G at slack 0), exploring after a phase change (G>M>A (5, 0)), a slack of 1
# (critic precision), and three that need neither (M>A>G (0, 0), Figure 3's (100, 0),
# the fan at 100).
PROBLEMS = {"A>M>G:0,0": "exploring under a constraint",
            "A>M>G:0,100": "exploring under a constraint",
            "G>M>A:5,0": "exploring after a phase change",
            "M>A>G:1,1": "slack 1",
            "M>A>G:0,0": "direct",
            "M>A>G:100,0": "direct",
            "A>G, M>G:100,100": "direct"}


def steps_to_correct(correct: np.ndarray, budgets: list[int]) -> list[float]:
    """Per seed (``correct [budget, seed]``), the smallest budget from which on it is
    LAR-correct at every budget measured (``inf`` if not at the largest)."""
    out = []
    for column in correct.T:
        wrong = np.flatnonzero(~column)
        first = 0 if not len(wrong) else wrong[-1] + 1
        out.append(float(budgets[first]) if first < len(budgets) else float("inf"))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--map", default="home")
    parser.add_argument("--problems", nargs="+", default=list(PROBLEMS), metavar="DAG:SLACK")
    parser.add_argument("--forms", nargs="+", default=["penalty", "restriction"])
    parser.add_argument("--budgets", nargs="+", type=int,
                        default=[500_000, 1_000_000, 1_500_000])
    parser.add_argument("--seeds", type=int, default=5)
    args = parser.parse_args()
    budgets = sorted(args.budgets)
    env = GridNav(load_map(args.map), random_start=True)
    rows = []
    head = " ".join(f"{b / 1e6:>5.2g}M" for b in budgets)
    print(f"{'form':<12} {'problem':<18} {head}  median steps to LAR-correct")
    for form in args.forms:
        config = TPOConfig(constraint=form)
        for problem in args.problems:
            dag, _, slack = problem.rpartition(":")
            t0 = time.perf_counter()
            correct = np.array([run_sweep(env, dag, [[float(v) for v in slack.split(",")]],
                                          list(range(args.seeds)), config, b).lar_correct[0]
                                for b in budgets])
            steps = steps_to_correct(correct, budgets)
            median = float(np.median(steps))
            counts = " ".join(f"{int(c.sum()):>4}/{args.seeds}" for c in correct)
            shown = (f"{median / 1e6:.2g} M" if np.isfinite(median)
                     else f"> {budgets[-1] / 1e6:.2g} M")
            print(f"{form:<12} {problem:<18} {counts}  {shown}  "
                  f"({time.perf_counter() - t0:.0f} s)", flush=True)
            rows.append({"form": form, "problem": problem, "family": PROBLEMS.get(problem),
                         "correct": correct.sum(axis=1).tolist(),
                         "steps_to_correct": [s if np.isfinite(s) else None for s in steps],
                         "median": median if np.isfinite(median) else None})
    print(json.dumps({"map": args.map, "seeds": args.seeds, "budgets": budgets,
                      "rows": rows}))


if __name__ == "__main__":
    main()
