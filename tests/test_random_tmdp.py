"""Random TMDPs (tpo.envs.random_tmdp) and any finite TMDP as a JAX env
(tpo.envs.tabular_env): the generator's promises, the env against its exact model,
and a learner trained and judged on one."""

import gymnasium as gym
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from tpo.algo import TPO, TPOConfig
from tpo.envs.random_tmdp import random_tmdp
from tpo.envs.spec import from_spec
from tpo.envs.tabular_env import TabularEnv
from tpo.errors import TPOError
from tpo.tabular import Judge, TabularTMDP, solve_lar


def reachable(model: TabularTMDP) -> np.ndarray:
    seen = np.zeros(model.n_states, bool)
    seen[model.start] = True
    frontier = [model.start]
    while frontier:
        s = frontier.pop()
        for nxt in model.successors[s][model.probs[s] > 0]:
            if not seen[nxt]:
                seen[nxt] = True
                frontier.append(int(nxt))
    return seen


@pytest.mark.parametrize("kwargs", [
    {}, {"states": 500, "actions": 8, "objectives": 6, "dag": "dag", "stochastic": True},
    {"states": 10, "actions": 2, "objectives": 2, "sparse": True, "observation": "embedding"},
    {"objectives": 5, "dag": "fan", "scale_spread": 1000.0, "slack": (0.5, 1.0)}])
def test_a_generated_problem_keeps_the_generator_s_promises(kwargs):
    problem = random_tmdp(7, **kwargs)
    again = random_tmdp(7, **kwargs)
    model, graph = problem.model, problem.graph
    np.testing.assert_array_equal(model.rewards, again.model.rewards)  # one seed, one problem
    np.testing.assert_array_equal(model.successors, again.model.successors)
    assert (model.n_states, model.n_actions) == (kwargs.get("states", 50),
                                                  kwargs.get("actions", 4))
    assert reachable(model).all() and not model.terminal[model.start]
    spread = kwargs.get("scale_spread", 100.0)
    assert problem.scales.max() / problem.scales.min() == pytest.approx(spread)
    for i, c in enumerate(problem.scales):  # each objective within its scale
        assert np.abs(model.rewards[..., i]).max() <= c + 1e-9
    lo, hi = kwargs.get("slack", (0.0, 1.0))
    for e in graph.edges:
        c = problem.scales[model.objectives.index(e.parent)]
        assert lo * c - 1e-9 <= e.slack <= hi * c + 1e-9
    k = kwargs.get("objectives", 3)
    assert len(graph.objectives) == k
    roots = [n for n in graph.objectives if not graph.parents(n)]
    if kwargs.get("dag", "chain") == "chain":
        assert len(graph.edges) == k - 1 and len(roots) == 1
    if kwargs.get("dag") == "fan":
        assert len(roots) == k - 1 and {e.child for e in graph.edges} == {graph.leaf}
    if kwargs.get("sparse"):
        assert (model.rewards != 0).mean() < 0.15
    width = problem.observations.shape[1]
    assert width == (model.n_states if problem.spec["observation"] == "onehot" else 16)


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"states": 9}, "states must be an integer from 10 to 500, got 9"),
    ({"actions": 9}, "actions must be an integer from 2 to 8"),
    ({"objectives": True}, "objectives must be an integer from 2 to 6"),
    ({"dag": "tree"}, "dag must be one of chain, fan, dag"),
    ({"slack": (0.5, 0.2)}, "slack must be a range (lo, hi) with 0 <= lo <= hi <= 1"),
    ({"scale_spread": 0.5}, "scale_spread must be a number from 1 to 1e6")])
def test_bad_generator_arguments_are_one_line(kwargs, message):
    with pytest.raises(TPOError) as err:
        random_tmdp(0, **kwargs)
    assert message in str(err.value) and "\n" not in str(err.value)


def test_the_jax_env_steps_as_its_model_says():
    problem = random_tmdp(3, states=20, actions=3, stochastic=True)
    env, model = problem.env(), problem.model
    s, a = 0, 1
    state = env.reset(jax.random.key(0), env.params)[1]
    keys = jax.random.split(jax.random.key(1), 20000)
    obs, nxt, reward, term, _ = jax.vmap(env.step_env, in_axes=(0, None, None, None))(
        keys, state, jnp.int32(a), env.params)
    counts = np.bincount(np.asarray(nxt.state), minlength=model.n_states) / len(keys)
    expected = np.zeros(model.n_states)
    np.add.at(expected, model.successors[s, a], model.probs[s, a])
    np.testing.assert_allclose(counts, expected, atol=0.015)  # 3 sigma at 20000 draws
    np.testing.assert_allclose(np.asarray(reward), np.broadcast_to(
        model.rewards[s, a], reward.shape), rtol=1e-6)
    np.testing.assert_array_equal(np.asarray(term), model.terminal[np.asarray(nxt.state)])
    np.testing.assert_array_equal(np.asarray(obs), problem.observations[np.asarray(nxt.state)])


def test_the_gymnasium_env_pays_a_vector_reward_and_reseeds_alike():
    problem = random_tmdp(4, objectives=4, observation="embedding")
    made = gym.make("tpo/RandomTMDP-v0", seed=4, objectives=4, observation="embedding")
    assert made.unwrapped.graph == problem.graph
    env = problem.gym_env()
    first, info = env.reset(seed=5)
    assert info["state"] == problem.model.start and env.reward_dim == 4
    np.testing.assert_allclose(first, problem.observations[0])
    _, reward, terminated, truncated, info = env.step(1)
    np.testing.assert_allclose(reward, problem.model.rewards[0, 1], rtol=1e-6)
    assert reward.shape == (4,) and env.reward_space.contains(reward)
    assert env.observation_space.shape == (16,) and not truncated
    assert terminated == bool(problem.model.terminal[info["state"]])


def test_specs_rebuild_the_env_and_any_model_becomes_a_jax_env():
    problem = random_tmdp(2, states=12, stochastic=True, observation="embedding")
    env = problem.env(random_start=True)
    again = from_spec(env.to_spec(), evaluation=True)
    np.testing.assert_array_equal(again.model.rewards, problem.model.rewards)
    assert not again.random_start and again.obs_shape == (16,)
    plain = TabularEnv(problem.model, max_steps=30)  # a model's arrays travel in its spec
    rebuilt = from_spec(plain.to_spec())
    np.testing.assert_array_equal(rebuilt.model.probs, problem.model.probs)
    assert rebuilt.obs_shape == (12,) and rebuilt.observation_onehots == ((0, 12),)
    with pytest.raises(TPOError, match="max_steps must be an integer from 1"):
        TabularEnv(problem.model, max_steps=0)


def test_tpo_trains_on_a_generated_problem_and_is_judged_exactly(tmp_path):
    problem = random_tmdp(1, states=15, actions=3, objectives=2, slack=(0.5, 0.5))
    config = TPOConfig(num_envs=8, num_steps=32)
    model = TPO(problem.env(random_start=True), problem.graph, config=config, seed=0,
                population=2)
    model.learn(2 * config.batch_size * 4)
    result = model.evaluate(episodes=4)
    assert set(result["exact"]["greedy"]) == set(problem.model.objectives)
    assert isinstance(result["lar_correct"], bool) and result["lar"]["feasible"] in (True, False)
    loaded = TPO.load(model.save(tmp_path / "m"))
    assert loaded.evaluate(episodes=4)["exact"] == result["exact"]


def rescaled(problem, c: float):
    """The problem with its first root's rewards, and the slack of every edge out of
    it, multiplied by ``c``: ``(model, graph, root)``."""
    graph = problem.graph
    root = graph.order[0]
    slacks = [e.slack * (c if e.parent == root else 1.0) for e in graph.edges]
    return problem.model.rescaled(root, c), graph.with_slack(slacks), root


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("c", [0.01, 100.0])
def test_lar_is_unchanged_when_one_objective_and_its_slacks_are_rescaled(seed, c):
    """Exact LAR of a feasible problem is scale-free: multiplying objective ``w``'s
    rewards, and the slack of every edge out of ``w``, by ``c`` multiplies ``w``'s
    values by ``c`` and changes no other value (value iteration converges at rewards
    of scale 1e4 too). A chain is always feasible; the relaxation of an infeasible
    problem sums violations of different objectives, and is not."""
    problem = random_tmdp(seed, states=40, objectives=3, scale_spread=100.0,
                          stochastic=True)
    model, graph = problem.model, problem.graph
    scaled, scaled_graph, root = rescaled(problem, c)  # a root: its slack matters
    before = solve_lar(model, graph).start_values()
    after = solve_lar(scaled, scaled_graph).start_values()
    for name, value in before.items():
        factor = c if name == root else 1.0
        assert after[name] == pytest.approx(factor * value, rel=1e-6, abs=1e-6 * factor)


@pytest.mark.parametrize("c", [0.01, 100.0])
def test_the_judge_gives_every_policy_the_same_verdicts_when_an_objective_is_rescaled(c):
    """The judge's tolerance is scale-free (``0.0025 R_k``): on feasible problems,
    rescaling one objective (and its slacks) changes no verdict of any policy, here
    LAR's own with 1-3 states' actions changed, 100 on each of 4 problems, where
    tolerances decide (with the maps' absolute 0.5, 42 of 400 verdicts change at
    ``c = 0.01``, where that objective's values all tie)."""
    rng = np.random.default_rng(7)
    for seed in range(4):
        problem = random_tmdp(seed, states=30, objectives=3, scale_spread=100.0,
                              stochastic=True, slack=(0.0, 0.3))
        scaled, scaled_graph, _ = rescaled(problem, c)
        judges = [Judge(solve_lar(m, g)) for m, g in ((problem.model, problem.graph),
                                                      (scaled, scaled_graph))]
        policies = []
        for _ in range(100):
            policy = judges[0].solution.policy.copy()
            changed = rng.integers(0, policy.size, rng.integers(1, 4))
            policy[changed] = rng.integers(0, problem.model.n_actions, changed.size)
            policies.append(policy)
        verdicts = [[(v.lar_correct, v.strict, v.same_values) for v in map(j, policies)]
                    for j in judges]
        assert verdicts[0] == verdicts[1], seed
        assert len(set(verdicts[0])) > 1  # the policies are not all judged alike
