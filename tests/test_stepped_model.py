"""Exact models of MO-Gymnasium's finite envs built by stepping them: checked against
the real env by random walks, and against values worked out from the envs' own
Pareto fronts and by hand."""

import gymnasium as gym
import mo_gymnasium  # noqa: F401  (registers the envs)
import numpy as np
import pytest

from tpo.envs.gym_adapter import observation_encoder
from tpo.envs.stepped_model import ACCESS, Access, mo_gym_model, stepped_model
from tpo.errors import TPOError
from tpo.graph import ObjectiveGraph
from tpo.tabular import solve_lar

GAMMA = 0.99
WALK = 3000


@pytest.mark.parametrize("env_id", sorted(ACCESS))
def test_random_walks_of_the_real_env_stay_inside_the_model(env_id):
    """Every step the real env takes (random actions, its own time limit and
    randomness) is one of the model's branches, with its reward; stochastic
    branches occur as often as the model says (a binomial z-score below 5)."""
    stepped = mo_gym_model(env_id, GAMMA)
    model, access = stepped.model, ACCESS[env_id]
    env = gym.make(env_id, disable_env_checker=True)
    encode, _ = observation_encoder(env.observation_space, env_id)
    terminal = model.n_states - 1
    rng = np.random.default_rng(0)
    obs, _ = env.reset(seed=1)
    state, events, expected, n_draws, steps = 0, 0, 0.0, 0, 0
    while steps < WALK:
        exact_obs = env_id != "breakable-bottles-v0" or max(
            env.unwrapped.bottles_dropped) <= 1  # the key keeps whether, not how many
        if exact_obs:
            np.testing.assert_array_equal(encode(obs), stepped.observations[state])
        a = int(rng.integers(model.n_actions))
        obs, reward, terminated, truncated, _ = env.step(a)
        steps += 1
        nxt = terminal if terminated else stepped.index(access.get(env.unwrapped))
        live = model.probs[state, a] > 0
        branch = np.flatnonzero(live & (model.successors[state, a] == nxt))
        matched = [b for b in branch
                   if np.allclose(stepped.branch_rewards[state, a, b], reward)]
        assert matched, (env_id, stepped.keys[state], a, nxt, reward)
        if live.sum() == 2:  # branch 0 is the drawn event, of probability p
            expected, n_draws = expected + model.probs[state, a, 0], n_draws + 1
            events += matched == [0]
        state = nxt
        if terminated or truncated:
            obs, _ = env.reset()
            state = 0
    if n_draws:
        spread = np.sqrt(max(expected * (1 - expected / n_draws), 1.0))
        assert abs(events - expected) < 5 * spread, (events, expected, n_draws)


def test_the_models_have_the_envs_sizes():
    sea = gym.make("deep-sea-treasure-v0").unwrapped.sea_map
    sizes = {e: (mo_gym_model(e).model.n_states, mo_gym_model(e).model.n_actions)
             for e in ACCESS}
    # deep sea: the map's open water (0) and the terminal state; fruit tree: the
    # 63 inner nodes of a depth-6 binary tree and the terminal state
    assert sizes["deep-sea-treasure-v0"] == (int((sea == 0).sum()) + 1, 4)
    assert sizes["fruit-tree-v0"] == (63 + 1, 2)
    # resource gathering: 25 cells x gold x gem, less the item cells without their
    # item, and the terminal state
    assert sizes["resource-gathering-v0"] == (25 * 4 - 2 * 2 - 2 * 2 + 1 + 1, 4)
    assert sizes["breakable-bottles-v0"][1] == 3


@pytest.mark.parametrize("env_id", ["deep-sea-treasure-v0", "deep-sea-treasure-concave-v0"])
def test_deep_sea_lexicographic_optima_are_the_ends_of_the_envs_own_front(env_id):
    model = mo_gym_model(env_id, GAMMA).model
    front = np.array(gym.make(env_id).unwrapped.pareto_front(gamma=GAMMA))
    treasure_first = solve_lar(model, ObjectiveGraph.parse("treasure>time", 0.0))
    time_first = solve_lar(model, ObjectiveGraph.parse("time>treasure", 0.0))
    richest, nearest = front[front[:, 0].argmax()], front[front[:, 1].argmax()]
    # the env pays float32 rewards (23.7 is 23.7000008): 1e-7 is one float32 ulp
    values = treasure_first.start_policy_values()
    assert [values["treasure"], values["time"]] == pytest.approx(richest, rel=1e-7)
    values = time_first.start_policy_values()
    assert [values["treasure"], values["time"]] == pytest.approx(nearest, rel=1e-7)


def test_fruit_tree_each_nutrient_alone_reaches_the_best_leaf_of_the_envs_front():
    model = mo_gym_model("fruit-tree-v0", GAMMA).model
    front = np.array(gym.make("fruit-tree-v0").unwrapped.pareto_front(gamma=GAMMA))
    for i, name in enumerate(model.objectives):
        best = solve_lar(model, ObjectiveGraph((name,))).start_values()[name]
        assert best == pytest.approx(front[:, i].max(), rel=1e-7)  # float32 rewards


def test_resource_gathering_has_the_documented_routes():
    model = mo_gym_model("resource-gathering-v0", GAMMA).model
    assert sorted(np.unique(model.probs)) == pytest.approx([0.0, 0.1, 0.9, 1.0], abs=1e-16)
    gem_first = solve_lar(model, ObjectiveGraph.parse("gem>gold>enemy", 0.0))
    gold_first = solve_lar(model, ObjectiveGraph.parse("gold>gem>enemy", 0.0))
    # the diamond straight home in 10 steps; the gold dodging both enemies in 12
    assert gem_first.start_policy_values() == pytest.approx(
        {"gem": GAMMA**9, "gold": 0.0, "enemy": 0.0}, abs=1e-12)
    assert gold_first.start_policy_values() == pytest.approx(
        {"gold": GAMMA**11, "gem": 0.0, "enemy": 0.0}, abs=1e-12)


def test_breakable_bottles_without_impact_carries_one_bottle_at_a_time():
    """From the far end: 4 steps left, pick up, 4 right (delivered at step 9), and
    again: 18 steps in all, never two bottles at once (each place on the way
    drops one of two with probability 0.1)."""
    model = mo_gym_model("breakable-bottles-v0", GAMMA).model
    values = solve_lar(model, ObjectiveGraph.parse("impact>time", 0.0)).start_policy_values()
    assert values["impact"] == 0.0
    assert values["time"] == pytest.approx(-(1 - GAMMA**18) / (1 - GAMMA), rel=1e-12)
    bottles = solve_lar(model, ObjectiveGraph.parse("impact>time>bottles", 0.0))
    assert bottles.start_policy_values()["bottles"] == pytest.approx(
        25 * (GAMMA**8 + GAMMA**17), rel=1e-12)


class _TwoDraws(gym.Env):
    observation_space = gym.spaces.Discrete(2)
    action_space = gym.spaces.Discrete(1)

    def __init__(self):
        self.s = 0

    def step(self, action):
        self.np_random.random(), self.np_random.random()
        return self.s, np.zeros(1), False, False, {}

    def reset(self, seed=None, options=None):
        super().reset(seed=seed)
        return self.s, {}


def test_a_step_that_draws_twice_is_refused_in_one_line():
    access = Access(("r",), lambda env: env.s, lambda env, key: setattr(env, "s", key),
                    lambda env: env.s)
    with pytest.raises(TPOError, match="draws 2 random numbers in one step"):
        stepped_model(_TwoDraws, access)
    with pytest.raises(TPOError, match="no stepped model of 'minecart-v0'"):
        mo_gym_model("minecart-v0")
