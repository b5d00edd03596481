"""Issue 6's demonstrations: TPO learns MO-Gymnasium envs stepped on the host, and
the outcome is checked against values computed without any learning.

Each learning claim is a count over seeds (tests/conftest.py).

- deep-sea-treasure-v0, ``treasure>time`` at slack 0: the lexicographic optimum is
  the largest treasure of the env's own Pareto front, by its shortest path.
- resource-gathering-v0, ``gem>gold>safety`` at slack 0, trained by the CLI: the
  run's evaluation equals LAR's exact values on a tabular model of the env built
  by driving the env's own ``step`` from every state.
"""

import itertools
import json

import gymnasium as gym
import mo_gymnasium  # noqa: F401  (registers the envs)
import numpy as np
import pytest

from tpo.algo import TPO, TPOConfig
from tpo.cli.main import main
from tpo.graph import ObjectiveGraph
from tpo.tabular import TabularTMDP, solve_lar

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


class _Draw:
    """Stands in for the env's random generator: ``random()`` returns ``u``."""

    def __init__(self, u: float) -> None:
        self.u = u

    def random(self) -> float:
        return self.u


def resource_gathering_model(gamma: float) -> TabularTMDP:
    """resource-gathering-v0 as a finite model: states (row, col, gold, gem) plus one
    terminal state; each transition found by putting the env in the state and
    stepping it, once with the enemy striking (its 10 % chance) and once not."""
    env = gym.make("resource-gathering-v0").unwrapped
    env.reset(seed=0)
    states = list(itertools.product(range(5), range(5), (0, 1), (0, 1)))
    index = {s: i for i, s in enumerate(states)}
    end = len(states)
    successors = np.full((end + 1, 4, 2), end)
    probs = np.zeros((end + 1, 4, 2))
    rewards = np.zeros((end + 1, 4, 3))
    for s, i in index.items():
        for a in range(4):
            outcomes = []
            for u in (0.0, 0.5):  # the enemy strikes when random() < 0.1
                env.current_pos = np.array(s[:2], np.int32)
                env.has_gold, env.has_gem = s[2], s[3]
                env.np_random = _Draw(u)
                obs, reward, terminated, _, _ = env.step(a)
                outcomes.append((end if terminated else index[tuple(map(int, obs))], reward))
            (s1, r1), (s2, r2) = outcomes
            p = (0.1, 0.9) if s1 != s2 or not np.array_equal(r1, r2) else (1.0, 0.0)
            successors[i, a] = (s1, s2)
            probs[i, a] = p
            rewards[i, a] = p[0] * r1 + p[1] * r2
    terminal = np.arange(end + 1) == end
    return TabularTMDP(successors, probs, rewards, ("safety", "gold", "gem"), gamma,
                       index[(4, 2, 0, 0)], terminal)


def test_the_resource_gathering_model_has_the_documented_routes():
    model = resource_gathering_model(GAMMA)
    gem_first = solve_lar(model, ObjectiveGraph.parse("gem>gold>safety", 0.0))
    gold_first = solve_lar(model, ObjectiveGraph.parse("gold>gem>safety", 0.0))
    # the diamond straight home in 10 steps; the gold dodging both enemies in 12
    assert gem_first.start_policy_values() == pytest.approx(
        {"gem": GAMMA**9, "gold": 0.0, "safety": 0.0})
    assert gold_first.start_policy_values() == pytest.approx(
        {"gold": GAMMA**11, "gem": 0.0, "safety": 0.0})


@pytest.mark.slow
def test_resource_gathering_chain_trained_by_the_cli_matches_the_exact_solution(
        tmp_path, seeds, at_least):
    exact = solve_lar(resource_gathering_model(GAMMA),
                      ObjectiveGraph.parse("gem>gold>safety", 0.0)).start_policy_values()
    outcomes, learned = [], []
    for seed in seeds(3):  # the host path steps Python envs: one seed after another
        out = tmp_path / f"rg-{seed}"
        assert main(["train", "--env", "mo-gymnasium:resource-gathering-v0",
                     "--objectives", "safety,gold,gem", "--dag", "gem>gold>safety",
                     "--slack", "0", "--steps", str(STEPS_RG), "--seed", str(seed),
                     "--out", str(out), "--quiet", "--episodes", "16"]) == 0
        result = json.loads((out / "eval.json").read_text())["mc"]["greedy"]["discounted"]
        values = {name: result[name]["mean"] for name in exact}
        learned.append(values)
        # Discounted float32 sums of at most 11 rewards in {0, 1, -1}: 1e-4 is ~1000 ulp.
        outcomes.append(values == pytest.approx(exact, rel=0, abs=1e-4))
    at_least(0.6, outcomes, {"exact": exact, "learned": learned})
