"""Is what TPO learns free of the rewards' units? Each generated problem of the
generality benchmark is trained as it is, and again with its root's rewards (and
the slacks of the edges out of the root) multiplied by 0.01 and by 100, and each
learned policy is judged exactly on its own model. A scale-free learner gives the
same verdicts at every scale, up to the learning's own noise.

    python benchmarks/rescaling.py --problems 10 --steps 1000000 --json out.json
"""

from __future__ import annotations

import argparse
import json
import time
from types import SimpleNamespace

from generality import shape, verdict_row
from tpo.algo import TPO
from tpo.envs.random_tmdp import random_tmdp
from tpo.envs.tabular_env import TabularEnv

SCALES = (1.0, 0.01, 100.0)


def case(i: int, c: float, steps: int, population: int) -> dict:
    """Problem ``i`` with its root scaled by ``c``, trained and judged."""
    problem = random_tmdp(i, **shape(i))
    graph = problem.graph
    root = graph.order[0]
    model = problem.model.rescaled(root, c)
    graph = graph.with_slack([e.slack * (c if e.parent == root else 1.0) for e in graph.edges])
    onehot = problem.spec["observation"] == "onehot"
    env = TabularEnv(model, None if onehot else problem.observations,
                     problem.spec["max_steps"], random_start=True)
    start = time.perf_counter()
    learner = TPO(env, graph, seed=i, population=population).learn(steps)
    scaled = SimpleNamespace(model=model, observations=problem.observations)
    return {"problem": i, "scale": c, "dag": graph.spec,
            **verdict_row(scaled, learner, graph),
            "seconds": round(time.perf_counter() - start, 1)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--problems", type=int, default=10)
    parser.add_argument("--first", type=int, default=0, help="the first problem's index")
    parser.add_argument("--steps", type=int, default=1_000_000)
    parser.add_argument("--population", type=int, default=4)
    parser.add_argument("--json", help="write the rows to this file")
    args = parser.parse_args()
    rows, unchanged, compared = [], 0, 0
    for i in range(args.first, args.first + args.problems):
        here = [case(i, c, args.steps, args.population) for c in SCALES]
        for row in here:
            print(json.dumps(row), flush=True)
        base = here[0]["lar_correct"]
        compared += len(here) - 1
        unchanged += sum(row["lar_correct"] == base for row in here[1:])
        rows += here
        if args.json:
            with open(args.json, "w") as f:
                json.dump(rows, f, indent=1)
    print(f"LAR-correct verdicts unchanged by rescaling: {unchanged}/{compared}; "
          f"LAR-correct at each scale: " + ", ".join(
              f"{c:g}: {sum(r['lar_correct'] for r in rows if r['scale'] == c)}"
              f"/{sum(r['scale'] == c for r in rows)}" for c in SCALES))


if __name__ == "__main__":
    main()
