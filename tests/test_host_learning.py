"""Issue 6's demonstrations: TPO learns MO-Gymnasium envs stepped on the host, and
the outcome is checked against values computed without any learning.

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


@pytest.mark.slow
def test_deep_sea_treasure_chain_at_slack_0_learns_the_lexicographic_optimum():
    front = gym.make("deep-sea-treasure-v0").unwrapped.pareto_front(gamma=1.0)
    best = max(front, key=lambda point: (point[0], point[1]))  # treasure, then time
    np.testing.assert_allclose(best, [23.7, -19.0])

    model = TPO("mo-gymnasium:deep-sea-treasure-v0", "treasure>time", slack=0.0,
                objectives=["treasure", "time"], seed=0)
    model.learn(400_000)
    greedy = model.evaluate(episodes=4)["mc"]["greedy"]
    learned = [greedy["undiscounted"][name]["mean"] for name in ("treasure", "time")]
    np.testing.assert_allclose(learned, best, atol=1e-4)
    assert greedy["length"] == 19


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
def test_resource_gathering_chain_trained_by_the_cli_matches_the_exact_solution(tmp_path):
    out = tmp_path / "rg"
    assert main(["train", "--env", "mo-gymnasium:resource-gathering-v0",
                 "--objectives", "safety,gold,gem", "--dag", "gem>gold>safety",
                 "--slack", "0", "--steps", "600000", "--seed", "0", "--out", str(out),
                 "--quiet", "--episodes", "16"]) == 0
    result = json.loads((out / "eval.json").read_text())["mc"]["greedy"]["discounted"]
    exact = solve_lar(resource_gathering_model(GAMMA),
                      ObjectiveGraph.parse("gem>gold>safety", 0.0)).start_policy_values()
    learned = {name: result[name]["mean"] for name in exact}
    assert learned == pytest.approx(exact, abs=1e-4)
