"""Issue 6's demonstrations: TPO learns MO-Gymnasium envs stepped on the host, and
the outcome is checked against values computed without any learning.

Each learning claim is a count over seeds (tests/conftest.py).

- deep-sea-treasure-v0, ``treasure>time`` at slack 0: the lexicographic optimum is
  the largest treasure of the env's own Pareto front, by its shortest path.
- resource-gathering-v0, ``gem>gold>enemy`` at slack 0, trained by the CLI: the
  run's evaluation equals LAR's exact values on the env's stepped model
  (``tpo.envs.stepped_model``).
"""

import json

import gymnasium as gym
import mo_gymnasium  # noqa: F401  (registers the envs)
import numpy as np
import pytest

from tpo.algo import TPO, TPOConfig
from tpo.cli.main import main
from tpo.envs.stepped_model import mo_gym_model
from tpo.graph import ObjectiveGraph
from tpo.tabular import solve_lar

GAMMA = TPOConfig().gamma
STEPS_DST = 600_000
STEPS_RG = 600_000


@pytest.mark.slow
def test_deep_sea_treasure_chain_at_slack_0_learns_the_lexicographic_optimum(seeds, at_least):
    front = gym.make("deep-sea-treasure-v0").unwrapped.pareto_front(gamma=1.0)
    best = max(front, key=lambda point: (point[0], point[1]))  # treasure, then time
    np.testing.assert_allclose(best, [23.7, -19.0])

    outcomes, learned = [], []
    for seed in seeds(4):  # the host path steps Python envs: one seed after another
        model = TPO("mo-gymnasium:deep-sea-treasure-v0", "treasure>time", slack=0.0,
                    objectives=["treasure", "time"], seed=seed).learn(STEPS_DST)
        greedy = model.evaluate(episodes=4)["mc"]["greedy"]
        values = [greedy["undiscounted"][name]["mean"] for name in ("treasure", "time")]
        learned.append(values)
        # Sums of at most 19 rewards with one decimal, in float32: 1e-4 is ~100 ulp.
        outcomes.append(np.allclose(values, best, rtol=0, atol=1e-4)
                        and greedy["length"] == 19)
    at_least(0.5, outcomes, {"learned": learned})


@pytest.mark.slow
def test_resource_gathering_chain_trained_by_the_cli_matches_the_exact_solution(
        tmp_path, seeds, at_least):
    exact = solve_lar(mo_gym_model("resource-gathering-v0", GAMMA).model,
                      ObjectiveGraph.parse("gem>gold>enemy", 0.0)).start_policy_values()
    outcomes, learned = [], []
    for seed in seeds(3):  # the host path steps Python envs: one seed after another
        out = tmp_path / f"rg-{seed}"
        assert main(["train", "--env", "mo-gymnasium:resource-gathering-v0",
                     "--objectives", "enemy,gold,gem", "--dag", "gem>gold>enemy",
                     "--slack", "0", "--steps", str(STEPS_RG), "--seed", str(seed),
                     "--out", str(out), "--quiet", "--episodes", "16"]) == 0
        result = json.loads((out / "eval.json").read_text())["mc"]["greedy"]["discounted"]
        values = {name: result[name]["mean"] for name in exact}
        learned.append(values)
        # Discounted float32 sums of at most 11 rewards in {0, 1, -1}: 1e-4 is ~1000 ulp.
        outcomes.append(values == pytest.approx(exact, rel=0, abs=1e-4))
    at_least(0.6, outcomes, {"exact": exact, "learned": learned})
