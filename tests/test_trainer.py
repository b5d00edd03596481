"""The TPO trainer: plain PPO learns, phases freeze their critics, seeds vmap."""

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from tpo.algo import constraints
from tpo.algo.config import ConfigError, TPOConfig
from tpo.algo.constraints import trace_decay
from tpo.algo.lagrangian import ancestral_advantages
from tpo.algo.networks import ValueNorm, scale_output
from tpo.algo.phases import Problem
from tpo.algo.train import Rollout, Trainer
from tpo.envs import OBJECTIVES, load_map
from tpo.envs.grid import GridNav
from tpo.experiments.sweep import run_sweep
from tpo.graph import ObjectiveGraph
from tpo.tabular import solve_lar


@pytest.fixture(scope="module")
def small():
    navmap = load_map("small")
    return GridNav(navmap, random_start=True), GridNav(navmap)


@pytest.mark.slow
def test_plain_ppo_learns_the_goal_exactly(small, seeds, at_least):
    train_env, eval_env = small
    config = TPOConfig()
    result = run_sweep(train_env, "goal", [[]], seeds(5), config, 200_000)
    best = solve_lar(eval_env.tabular(config.gamma).model,
                     ObjectiveGraph.parse("goal")).start_values()["goal"]
    assert best == pytest.approx(-(1 - 0.99**8) / 0.01)  # the 8-step shortest path
    goal = result.exact[0, :, OBJECTIVES.index("goal")]
    # Exact values are float64 solves: an optimal policy's equals LAR's to 1e-9.
    at_least(0.8, np.abs(goal - best) <= 1e-6, {"exact goal": goal.tolist()})


def two_updates_a_phase(env, dag, slack, **config):
    """A trainer of ``dag`` with two updates of 4 envs x 32 steps a phase, its initial
    state, and its jitted ``run``."""
    graph = ObjectiveGraph.parse(dag, slack, objectives=OBJECTIVES)
    config = TPOConfig(num_envs=4, num_steps=32, **config)
    phases = Trainer(env, graph, config, 10**6).problem.n_phases
    trainer = Trainer(env, graph, config, phases * 4 * 32 * 2)
    return trainer, trainer.init(jax.random.key(0)), jax.jit(trainer.run, static_argnums=2)


@pytest.mark.parametrize("constraint", ["penalty", "restriction"])
def test_later_phases_leave_earlier_critics_frozen(small, constraint):
    train_env, _ = small
    trainer, state, run = two_updates_a_phase(train_env, "M>A>G", 0, constraint=constraint)
    monitor, goal = 0, 2  # critic heads are phases, in topological order
    after_first, _ = run(state, trainer.slack_array(), int(trainer.phase_start[1]))
    final, metrics = run(after_first, trainer.slack_array(),
                         trainer.num_updates - int(trainer.phase_start[1]))
    assert np.asarray(metrics["phase"]).tolist() == [1, 1, 2, 2]

    def head(state, i):
        return jax.tree.map(lambda x: np.asarray(x[i]), state.params["critics"]["heads"])

    first, later = head(after_first, monitor), head(final, monitor)
    for layer in ("layer_0", "layer_1"):  # the frozen head's hidden layers and its value
        assert all(np.array_equal(first[layer][p], later[layer][p]) for p in first[layer])
    out_first, out_later = first["out"]["kernel"], later["out"]["kernel"]
    assert np.array_equal(out_first[:, 0], out_later[:, 0])
    # restriction: its advantage outputs keep learning (on the frozen hidden layers)
    assert np.array_equal(out_first[:, 1:], out_later[:, 1:]) == (constraint == "penalty")
    trained_goal, first_goal = head(final, goal), head(after_first, goal)
    assert not np.array_equal(first_goal["layer_0"]["kernel"],
                              trained_goal["layer_0"]["kernel"])


def test_completion_phases_follow_the_leaf_at_zero_slack():
    chain = Problem.build(ObjectiveGraph.parse("M>A>G", [1, 2], objectives=OBJECTIVES),
                          OBJECTIVES, TPOConfig(completion=True))
    m, a, g = (OBJECTIVES.index(n) for n in ("monitor", "avoid", "goal"))
    assert chain.reward.tolist() == [m, a, g, m, a]  # then the leaf's ancestors, roots first
    assert chain.phase_names[3:] == ("monitor (completion)", "avoid (completion)")
    # constraints: edge M->A on head 0, edge A->G on head 1, the leaf (head 2) and the
    # first completion phase (head 3) at zero slack (index n_edges = 2)
    assert chain.head.tolist() == [0, 1, 2, 3]
    assert chain.slack_index.tolist() == [0, 1, 2, 2]
    assert chain.active.tolist() == [[0, 0, 0, 0], [1, 0, 0, 0], [1, 1, 0, 0],
                                     [1, 1, 1, 0], [1, 1, 1, 1]]
    fan = Problem.build(ObjectiveGraph.parse("A>G, M>G", objectives=OBJECTIVES),
                        OBJECTIVES, TPOConfig(completion=True))
    assert fan.reward.tolist() == [a, m, g, a, m]
    assert fan.active.tolist() == [[0, 0, 0, 0], [0, 0, 0, 0], [1, 1, 0, 0],
                                   [1, 1, 1, 0], [1, 1, 1, 1]]
    paper = Problem.build(ObjectiveGraph.parse("M>A>G", objectives=OBJECTIVES),
                          OBJECTIVES, TPOConfig())
    assert paper.reward.tolist() == [m, a, g] and paper.head.tolist() == [0, 1]


def test_a_fan_learns_its_roots_completion_after_the_leaf():
    a, m, g = (OBJECTIVES.index(n) for n in ("avoid", "monitor", "goal"))
    fan = Problem.build(ObjectiveGraph.parse("A>G, M>G", [3, 4], objectives=OBJECTIVES),
                        OBJECTIVES, TPOConfig())
    assert fan.phase_names == ("avoid", "monitor", "goal", "monitor (under avoid)")
    assert fan.reward.tolist() == [a, m, g, m]
    # constraints: edges A->G (head 0) and M->G (head 1), then avoid (head 0) at zero
    # slack (index n_edges = 2), kept by the last phase alone
    assert fan.head.tolist() == [0, 1, 0] and fan.slack_index.tolist() == [0, 1, 2]
    assert fan.active.tolist() == [[0, 0, 0], [0, 0, 0], [1, 1, 0], [0, 0, 1]]
    assert fan.start.tolist() == [-1, 0, 1, 1]  # from monitor's own policy
    assert fan.reference == 2  # the run's own policy is the leaf's
    # three roots: each later one under the phase that holds the roots before it
    three = Problem.build(ObjectiveGraph.parse("goal>avoid, monitor>avoid, x>avoid",
                                               objectives=("goal", "avoid", "monitor", "x")),
                          ("goal", "avoid", "monitor", "x"), TPOConfig())
    assert three.phase_names[4:] == ("monitor (under goal)", "x (under goal+monitor)")
    assert three.head.tolist()[3:] == [0, 4] and three.active[5].tolist() == [0, 0, 0, 1, 1]
    assert three.start.tolist()[4:] == [1, 2] and three.reference == 3
    # none without the end-of-run choice, nor beside the full completion, nor in a
    # config saved before it (a model of 3 phases loads as one)
    for config in (TPOConfig(select=False), TPOConfig(completion=True),
                   TPOConfig(roots_completion=False),
                   TPOConfig.from_saved({"select": True}, 7)):
        assert "(under" not in " ".join(Problem.build(
            ObjectiveGraph.parse("A>G, M>G", objectives=OBJECTIVES), OBJECTIVES,
            config).phase_names)
    chain = Problem.build(ObjectiveGraph.parse("M>A>G", objectives=OBJECTIVES), OBJECTIVES,
                          TPOConfig())
    assert chain.n_phases == 3 and chain.reference == 2 and chain.start.tolist() == [-1, 0, 1]


def test_the_roots_completion_starts_from_its_roots_policy_and_the_leaf_answers(small):
    train_env, _ = small
    trainer, state, run = two_updates_a_phase(train_env, "A>G, M>G", 100)
    assert trainer.problem.n_phases == 4
    state, _ = run(state, trainer.slack_array(), int(trainer.phase_start[3]))
    actor = jax.tree.map(np.asarray, state.params["actor"])
    snapshots = jax.tree.map(np.asarray, state.snapshots)
    leaves = jax.tree.leaves(jax.tree.map(lambda x, s: (np.array_equal(x, s[1]),
                                                        np.array_equal(x, s[2])),
                                          actor, snapshots))
    assert all(leaves[0::2]) and not all(leaves[1::2])  # monitor's policy, not the leaf's
    state, _ = run(state, trainer.slack_array(), trainer.num_updates - int(trainer.phase_start[3]))
    assert int(trainer.acting(state, trainer.slack_array()).phase) == 2  # the leaf's constraints
    assert int(trainer.acting(state, trainer.slack_array(),
                              jnp.int32(trainer.problem.reference)).phase) == 2


def test_restricted_rollouts_act_within_the_admissible_actions(small):
    train_env, _ = small
    graph = ObjectiveGraph.parse("A>G", 0, objectives=OBJECTIVES)
    config = TPOConfig(num_envs=8, num_steps=64, constraint="restriction", completion=True,
                       explore=0.25)
    trainer = Trainer(train_env, graph, config, 3 * config.batch_size * 3)
    assert trainer.form.name == "restriction" and trainer.problem.n_phases == 3
    state = trainer.init(jax.random.key(0))
    state, _ = jax.jit(trainer.run, static_argnums=2)(state, trainer.slack_array(), 4)
    _, rollout, _ = trainer.collect(state, trainer.slack_array())
    allowed = np.asarray(rollout.allowed)
    taken = np.take_along_axis(allowed, np.asarray(rollout.action)[..., None], -1)[..., 0]
    explore = np.asarray(rollout.explore) > 0
    assert taken[~explore].all()  # the policy's own steps; exploring ones take any action
    assert not taken[explore].all()
    assert 0 < allowed.mean() < 1  # the avoid critic excludes some actions
    assert explore.mean() == pytest.approx(0.25, abs=0.05)


class Step(NamedTuple):
    advantage: float
    penalty: float
    target: float  # the goal critic's
    avoid_reward: float


def goal_phase_step(train_env, slack: float, avoid_advantage: float, total: int = 2,
                    update: int = 0, **config) -> Step:
    """One goal-phase transition of ``A>G`` at ``slack`` (``s' = s``, a rollout of one
    step, at ``update``) whose one-step avoid advantage ``r - (1 - gamma) V_avoid(s)``
    is ``avoid_advantage``."""
    graph = ObjectiveGraph.parse("A>G", slack, objectives=OBJECTIVES)
    config = TPOConfig(num_envs=1, num_steps=1, num_minibatches=1, **config)
    trainer = Trainer(train_env, graph, config, total)
    state = trainer.init(jax.random.key(0)).replace(update=jnp.int32(update))
    obs = state.obs[None]  # [T=1, E=1, D]
    v_avoid = float(trainer.values(state, obs)[0, 0, 0, 0])  # head 0: avoid
    reward = np.zeros((1, 1, len(OBJECTIVES)), np.float32)
    reward[..., OBJECTIVES.index("avoid")] = avoid_advantage + (1 - 0.99) * v_avoid
    zeros = jnp.zeros((1, 1))
    rollout = Rollout(obs=obs, action=jnp.zeros((1, 1), jnp.int32), log_prob=zeros,
                      reward=jnp.asarray(reward), final_obs=obs, terminated=zeros, done=zeros,
                      allowed=None, explore=zeros)
    batch, penalties, _ = trainer.lagrangian_targets(state, trainer.slack_array(), rollout,
                                                     jnp.int32(1))
    return Step(float(batch.advantage[0]), float(penalties[0, 0]), float(batch.target[0]),
                float(reward[0, 0, OBJECTIVES.index("avoid")]))


@pytest.mark.parametrize(("slack", "gap", "penalty"), [
    (1.0, 0.8, 0.1),  # the margin: 0.15 x avoid's reward range 2 = 0.3 below the slack
    (1.0, 0.6, 0.0),
    (0.4, 0.3, 0.1),  # at most half the slack
    (0.0, 0.25, 0.25),  # no margin at slack 0
    (100.0, 99.8, 0.1)])
def test_the_penalty_counts_from_the_slack_less_the_margin(small, slack, gap, penalty):
    """A goal-phase transition whose one-step avoid advantage is ``-gap``: its penalty
    is ``max(0, gap - (slack - min(0.3, slack / 2)))``."""
    train_env, _ = small
    graph = ObjectiveGraph.parse("A>G", slack, objectives=OBJECTIVES)
    assert Trainer(train_env, graph, TPOConfig(), 10**6).terms.margin.tolist() == pytest.approx(
        [0.3])
    assert goal_phase_step(train_env, slack, -gap).penalty == pytest.approx(penalty, abs=1e-4)


@pytest.mark.parametrize(("slack", "advantage", "penalty"), [
    (0.0, -0.25, 0.25),  # as the paper's at zero slack where the advantage is negative
    (0.0, 0.3, -0.3),  # but a positive one is credited, so that the critic's errors cancel
    (1.0, -0.8, 0.1),  # above zero slack the paper's, from the slack less the margin
    (1.0, 0.3, 0.0)])
def test_a_telescoping_penalty_charges_the_advantage_itself_at_zero_slack(
        small, slack, advantage, penalty):
    train_env, _ = small
    assert goal_phase_step(train_env, slack, advantage, telescope="all").penalty == pytest.approx(
        penalty, abs=1e-4)


@pytest.mark.parametrize(("advantage", "penalty"), [(-0.25, 0.0), (0.3, 0.0), (-0.9, 0.4),
                                                    (0.8, -0.3)])
def test_a_dead_zone_charges_a_telescoped_advantage_beyond_it(small, advantage, penalty):
    """``dead_zone`` 0.25 of the avoid's one-step reward range (2 on ``small``): an
    advantage within 0.5 of 0 charges nothing; beyond it, all but the 0.5."""
    train_env, _ = small
    assert goal_phase_step(train_env, 0.0, advantage, telescope="all",
                           dead_zone=0.25).penalty == pytest.approx(penalty, abs=1e-4)


@pytest.mark.parametrize(("dag", "telescope", "zones"), [
    ("M>A>G", "all", [0.0, 1.0]), ("A>M>G", "all", [1.0, 0.0]),
    ("A>G, M>G", "all", [1.0, 0.0, 1.0]), ("G>M>A", "all", [0.0, 0.0]),
    ("M>A>G", "roots", [0.0, 0.0])])  # avoid is no root here: its constraint is rectified
def test_the_dead_zone_is_a_telescoping_costs_alone(small, dag, telescope, zones):
    """Only a telescoping constraint whose parent is a cost (avoid: rewards -2 to 0)
    gets the dead zone (0.5 of avoid's range 2); monitor's (-1 to 1) and the goal's
    (-1) charge every step of progress they lose."""
    train_env, _ = small
    graph = ObjectiveGraph.parse(dag, 0.0, objectives=OBJECTIVES)
    config = TPOConfig(dead_zone=0.5, telescope=telescope)
    assert Trainer(train_env, graph, config, 10**6).terms.dead_zone.tolist() == zones


@pytest.mark.parametrize(("dag", "telescoped", "loose"), [
    ("M>A>G", [True, False], [False, True]),  # A's own constraint could pay for a gain
    ("A>G, M>G", [True, True, True], [False] * 3),  # roots; the roots' completion's too
    ("G>M>A", [True, False], [False, True])])
def test_telescope_roots_telescopes_the_roots_constraints_only(small, dag, telescoped, loose):
    """``telescope = "roots"`` (the default): a zero-slack constraint whose parent is a
    root telescopes; the others are rectified from the tolerance, as the completion's."""
    train_env, _ = small
    graph = ObjectiveGraph.parse(dag, 0.0, objectives=OBJECTIVES)
    trainer = Trainer(train_env, graph, TPOConfig(), 10**6).terms
    assert (trainer.telescoped.tolist(), trainer.loose.tolist()) == (telescoped, loose)
    done = Trainer(train_env, graph, TPOConfig(completion=True), 10**6).terms
    edges = len(graph.edges)  # no roots' completion beside the completion phases
    assert done.telescoped.tolist() == telescoped[:edges] + [False] * 2  # the completion's
    assert done.loose.tolist() == loose[:edges] + [True] * 2
    for mode, flag in (("off", False), ("all", True)):
        every = Trainer(train_env, graph, TPOConfig(telescope=mode), 10**6).terms
        assert every.telescoped.tolist() == [flag] * len(telescoped) and not every.loose.any()


def test_a_loose_zero_slack_constraint_counts_from_the_tolerance(small):
    """``M>A>G`` at slack 0: the goal phase's constraint on the avoid (whose own parent
    is the monitor) is rectified from 0.2 x avoid's reward range 2 = 0.4."""
    train_env, _ = small
    graph = ObjectiveGraph.parse("M>A>G", 0.0, objectives=OBJECTIVES)
    trainer = Trainer(train_env, graph, TPOConfig(), 10**6)
    assert trainer.terms.tolerance.tolist() == pytest.approx([0.4, 0.4])  # M -> A, A -> G
    # Terminal transitions with zero values: each phase's one-step advantage is its reward.
    reward = np.zeros((3, len(OBJECTIVES)), np.float32)
    reward[:, OBJECTIVES.index("avoid")] = [-1.0, -0.3, 0.2]
    reward[:, OBJECTIVES.index("monitor")] = [0.0, 0.0, 0.5]

    def penalty(state):
        terms, zeros = trainer.terms, jnp.zeros((3, 3))
        advantages = ancestral_advantages(jnp.asarray(reward)[:, terms.reward], zeros, zeros,
                                          jnp.ones(3), 0.99)
        return constraints.penalty(terms, advantages, trainer.slack_array(), jnp.int32(2),
                                   trainer.loose_tolerance(state))

    state = trainer.init(jax.random.key(0))
    # avoid: max(0, 1 - 0.4), max(0, 0.3 - 0.4), 0; monitor (telescoped): 0, 0, -0.5
    np.testing.assert_allclose(penalty(state), [0.6, 0.0, -0.5], atol=1e-6)
    # The second design counts it from 0.1 x the avoid head's value std, at least 0.02:
    # fresh statistics have std 1 (tolerance 0.1); a spread of 0.01 gives the floor.
    second = trainer.init(jax.random.key(0), design=1)
    np.testing.assert_allclose(penalty(second), [0.9, 0.2, -0.5], atol=1e-6)
    ones = jnp.ones(3)
    narrow = second.replace(value_norm=ValueNorm(-ones, ones + 1e-4, ones))
    np.testing.assert_allclose(trainer.loose_tolerance(narrow), [0.02, 0.02], atol=1e-6)
    np.testing.assert_allclose(penalty(narrow), [0.98, 0.28, -0.5], atol=1e-6)
    # and traces the penalty by gamma alone
    assert float(trace_decay(trainer.terms, second.design)) == pytest.approx(0.99)
    assert float(trace_decay(trainer.terms, state.design)) == pytest.approx(0.99 * 0.95)


@pytest.mark.parametrize("dag, expected", [
    # ranges on the grids: goal 1, avoid 2 (a bump costs 1 more), monitor 2
    # only the leaf breaks ties: an inner phase keeps every action it is indifferent
    # among open to its descendants
    ("M>A>G", [[0, 0, 0], [0, 0, 0], [0.1 * 1 / 2, 0.01 * 1 / 2, 0]]),
    ("A>G, M>G", [[0, 0, 0, 0], [0, 0, 0, 0], [0.1 * 1 / 2, 0.01 * 1 / 2, 0, 0],
                  [0, 0, 0, 0]]),  # roots A, M; the roots' completion breaks none
    ("G>A", [[0, 0], [0.1 * 2 / 1, 0]])])
def test_tie_break_weighs_the_leaf_s_ancestors_roots_first(small, dag, expected):
    train_env, _ = small
    graph = ObjectiveGraph.parse(dag, objectives=OBJECTIVES)
    terms = Trainer(train_env, graph, TPOConfig(), 10**6).terms
    np.testing.assert_allclose(terms.tie, expected, rtol=1e-6)
    off = Trainer(train_env, graph, TPOConfig(tie_break=0.0), 10**6).terms
    assert not off.tie.any()


@pytest.mark.parametrize("avoid_advantage, gain", [
    (-0.7, 0.1 * 1 / 2 * -0.7),  # tie_break * range_goal / range_avoid * -0.7
    (-90.0, -0.1 * 1),  # bounded by tie_break * range_goal (a terminal's lost value-to-go)
    (30.0, 0.1 * 1)])
def test_the_tie_break_adds_the_ancestors_advantages_bounded(small, avoid_advantage, gain):
    """A goal-phase transition of A>G with a given one-step avoid advantage: its
    advantage gains the weighted avoid advantage, at most ``tie_break * range_goal``
    in size (a rollout of one step: GAE is the one-step advantage)."""
    train_env, _ = small
    off = goal_phase_step(train_env, 100.0, avoid_advantage, tie_break=0.0)
    on = goal_phase_step(train_env, 100.0, avoid_advantage, tie_break=0.1)
    assert on.advantage - off.advantage == pytest.approx(gain, abs=1e-5)
    assert on.target == off.target


@pytest.mark.parametrize("avoid_advantage", [-0.7, -90.0, 30.0])
def test_the_leaf_s_own_critic_can_value_the_ancestors_rewards(small, avoid_advantage):
    """``tie_critic = "leaf"``: the same transition's avoid reward ``r``, weighted by
    ``tie_break * range_goal / range_avoid = 0.05``, joins the goal reward, so the
    advantage and the goal critic's target both gain ``0.05 r``, with no bound."""
    train_env, _ = small
    off = goal_phase_step(train_env, 100.0, avoid_advantage, tie_break=0.0)
    on = goal_phase_step(train_env, 100.0, avoid_advantage, tie_critic="leaf")
    gain = 0.1 * 1 / 2 * on.avoid_reward
    assert on.avoid_reward == pytest.approx(avoid_advantage, abs=0.05)  # (1 - gamma) V small
    assert on.advantage - off.advantage == pytest.approx(gain, abs=1e-5)
    assert on.target - off.target == pytest.approx(gain, abs=1e-5)


def test_seeds_and_slacks_vmap_in_one_compiled_run(small):
    """docs/design.md §5's hang: parameters initialised outside the vmapped function."""
    train_env, _ = small
    graph = ObjectiveGraph.parse("A>G", 0, objectives=OBJECTIVES)
    trainer = Trainer(train_env, graph, TPOConfig(num_envs=4, num_steps=16), 2 * 4 * 16 * 2)
    states = [trainer.init(jax.random.key(s)) for s in range(3)]
    states = jax.tree.map(lambda *x: jnp.stack(x), *states)
    slacks = jnp.array([[0.0], [1.0], [100.0]])
    run = jax.jit(jax.vmap(lambda s, eta: trainer.run(s, eta, trainer.num_updates)))
    final, metrics = run(states, slacks)
    assert np.asarray(final.update).tolist() == [4, 4, 4]
    assert metrics["penalty"].shape == (3, 4)
    first = jax.tree.leaves(final.params["actor"])[0]
    assert not np.allclose(first[0], first[1])  # seeds differ


def test_phase_split_and_bad_budgets(small):
    train_env, _ = small
    graph = ObjectiveGraph.parse("M>A>G", objectives=OBJECTIVES)
    config = TPOConfig(num_envs=4, num_steps=8, phase_fractions=(1, 1, 2))
    trainer = Trainer(train_env, graph, config, 4 * 8 * 40)
    assert trainer.phase_updates.tolist() == [10, 10, 20]
    huge = TPOConfig(num_envs=4, num_steps=8, phase_fractions=(1e308,) * 3)
    assert Trainer(train_env, graph, huge, 4 * 8 * 30).phase_updates.tolist() == [10, 10, 10]
    with pytest.raises(ConfigError, match="total_timesteps must be an integer from 96 "):
        Trainer(train_env, graph, config, 50)
    with pytest.raises(ConfigError, match="phase_fractions has 2 values for 3 phase"):
        Trainer(train_env, graph, TPOConfig(phase_fractions=(1, 1)), 10**6)


def test_schedules_restart_with_every_phase(small):
    """The learning rate anneals to 0 and the entropy weight from ``ent_coef`` to
    ``ent_coef_end``, linearly within each phase (phases of 10, 10 and 20 updates)."""
    train_env, _ = small
    graph = ObjectiveGraph.parse("M>A>G", objectives=OBJECTIVES)
    config = TPOConfig(num_envs=4, num_steps=8, phase_fractions=(1, 1, 2),
                       learning_rate=1e-3, ent_coef=0.1, ent_coef_end=0.02)
    trainer = Trainer(train_env, graph, config, 4 * 8 * 40)
    ent = [float(trainer.ent_coef(u)) for u in (0, 5, 10, 15, 20, 30)]
    np.testing.assert_allclose(ent, [0.1, 0.06, 0.1, 0.06, 0.1, 0.06], rtol=1e-6)
    lr = [float(trainer.learning_rate(u)) for u in (0, 5, 10, 30)]
    np.testing.assert_allclose(lr, [1e-3, 5e-4, 1e-3, 5e-4], rtol=1e-6)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"num_envs": 0}, "num_envs must be an integer from 1 to 65536"),
        ({"num_envs": 10**20}, "num_envs must be an integer from 1 to 65536"),
        ({"num_minibatches": 3}, "num_minibatches (3) must divide"),
        ({"learning_rate": -1.0}, "learning_rate must be a finite number > 0"),
        ({"gamma": 1.0}, "gamma must be in [0, 1)"),
        ({"beta": -2.0}, "beta must be a finite number >= 0"),
        ({"advantage": "eq10"}, "advantage must be one of traced, immediate, penalized"),
        ({"advantage": "literal"}, "advantage must be one of traced, immediate, penalized"),
        ({"telescope": "roots only"}, "telescope must be one of off, roots, all, got "),
        ({"telescope": 1}, "telescope must be one of off, roots, all, got 1"),
        ({"hidden": (64, 0)}, "hidden must be 1 to 16 layer widths from 1 to 4096"),
        ({"hidden": (3_000_000_000,)}, "hidden must be 1 to 16 layer widths"),
        ({"anneal_lr": 1}, "anneal_lr must be true or false"),
        ({"tie_break": 1.0}, "tie_break must be in [0, 1), got 1.0"),
        ({"tie_break": -0.1}, "tie_break must be a finite number >= 0"),
        ({"select_penalty": -1.0}, "select_penalty must be a finite number >= 0"),
        ({"second_tolerance": float("inf")}, "second_tolerance must be a finite number >= 0"),
        ({"action_bins": 1}, "action_bins must be 0 (Gaussian) or an integer from 2 to 256"),
        ({"action_bins": True}, "action_bins must be 0 (Gaussian) or an integer"),
    ],
)
def test_bad_config_is_rejected(kwargs, message):
    with pytest.raises(ConfigError) as err:
        TPOConfig(**kwargs)
    assert message in str(err.value)


def test_config_round_trips_through_toml_text():
    config = TPOConfig(hidden=(32, 32), beta="auto", phase_fractions=(1.0, 2.0))
    assert TPOConfig.from_toml(config.to_toml()) == config
    with pytest.raises(ConfigError, match="unknown config key"):
        TPOConfig.from_dict({"lr": 1.0})
    with pytest.raises(ConfigError, match="unknown config key"):
        TPOConfig.from_dict({"beta_warmup": 0.0})  # dropped in format 8


@pytest.mark.parametrize(("data", "message"), [
    ({"critic_refit": 0.1}, "config key critic_refit was removed in tpo 0.2"),
    ({"beta_warmup": 0.2}, "this config sets beta_warmup, which tpo no longer has"),
    ({"advantage": "literal"}, 'this config sets advantage = "literal"')])
def test_a_format_7_config_reads_as_it_meant_or_names_its_dropped_switch(data, message):
    old = TPOConfig.from_saved({"beta_warmup": 0.0, "telescope": True}, 7)
    assert (old.telescope, old.margin, old.select, old.advantage) == ("all", 0.0, False,
                                                                      "penalized")
    assert TPOConfig.from_saved({}, 7).mixed_population is False
    with pytest.raises(ConfigError, match=message):
        TPOConfig.from_saved(data, 7)


def test_profiles_apply_in_order_under_the_values_given():
    assert TPOConfig.from_profile("grid") == TPOConfig()
    both = TPOConfig.from_profile("continuous,paper", "discretized", num_envs=8)
    assert (both.telescope, both.advantage, both.tie_critic, both.gae_lambda) == (
        "off", "penalized", "leaf", 0.98)  # paper's over continuous's
    assert (both.action_bins, both.num_envs, both.select) == (5, 8, False)
    assert TPOConfig.from_profile(["restriction"]).constraint == "restriction"
    with pytest.raises(ConfigError, match="unknown profile 'fast': choose from grid, "):
        TPOConfig.from_profile("grid,fast")


def test_softened_warm_start_keeps_greedy_actions_and_raises_entropy(small):
    train_env, eval_env = small
    trainer = Trainer(train_env, ObjectiveGraph.parse("goal"), TPOConfig(), 10**5)
    actor = trainer.init_params(jax.random.key(0))["actor"]
    actor = jax.tree.map(lambda x: x * 50, actor)  # a sharp policy
    obs = jnp.asarray(eval_env.tabular_observations())
    before = trainer.restricted(actor, obs, None).logits
    after = trainer.restricted(scale_output(actor, jnp.float32(0.2)), obs, None).logits
    assert np.allclose(after, before * 0.2, rtol=1e-5, atol=1e-4)  # logits / temperature 5
    assert np.array_equal(np.argmax(after, 1), np.argmax(before, 1))

    def ent(logits):
        p = jax.nn.softmax(logits)
        return float(-(p * jnp.log(p + 1e-12)).sum(1).mean())

    assert ent(after) > ent(before)


def test_one_critic_head_equals_its_column_of_all_heads():
    from tpo.algo.networks import Critics, orthogonalize

    critics = Critics((16, 16), 3, n_out=2)
    obs = jax.random.normal(jax.random.key(1), (5, 7))
    params = orthogonalize(critics.init(jax.random.key(0), obs)["params"], critics.out_gain)
    every = critics.apply({"params": params}, obs)
    assert every.shape == (5, 3, 2)
    # Outputs of unit scale from float32 sums of 16 products: the batched and the single
    # head may sum in another order (rounding ~1e-7), so an absolute tolerance of 1e-6.
    for column in range(3):
        np.testing.assert_allclose(critics.head(params, jnp.int32(column), obs),
                                   every[:, column], rtol=0, atol=1e-6)


def test_a_first_layer_reads_one_hot_blocks_by_hand():
    """InputDense: with kernel rows k_i = (i + 1, -i - 1) and bias (1, 0), blocks
    (4, 7) and (1, 4) (in any order): the input (0.5 | 0, 2, 0 | 0, 0, 0) gives 0.5 k_0 + 2 k_2 +
    bias = (7.5, -6.5) (a block of zeros adds nothing), (0 | 0, 0, 1 | 0, 3, 0) gives
    k_3 + 3 k_5 + bias = (23, -22)."""
    from tpo.algo.networks import InputDense

    def nn_init(key, shape, dtype):
        return jnp.stack([jnp.arange(1.0, 8.0), -jnp.arange(1.0, 8.0)], -1)

    layer = InputDense(2, ((4, 7), (1, 4)), nn_init)
    x = jnp.array([[0.5, 0, 2, 0, 0, 0, 0], [0, 0, 0, 1, 0, 3, 0]])
    params = layer.init(jax.random.key(0), x)
    params = jax.tree.map(lambda p: p + jnp.array([1.0, 0.0]) if p.ndim == 1 else p, params)
    np.testing.assert_allclose(layer.apply(params, x), [[7.5, -6.5], [23, -22]])
    for bad in [((0, 5), (3, 7)), ((1, 4), (1, 4)), ((2, 2),), ((5, 9),)]:
        with pytest.raises(ValueError, match="not disjoint, non-empty ranges of an input "
                                             "of 7 numbers"):
            InputDense(2, bad, nn_init).init(jax.random.key(0), x)


@pytest.mark.parametrize("observation", ["factored+onehot", "factored", "onehot"])
def test_one_hot_blocks_change_no_number_of_the_networks(observation):
    """The actor and critics (all heads, and one alone) that gather the grid's one-hot
    blocks are initialised exactly as plain dense layers, and agree with them in
    outputs and gradients on every cell of `home` (factored: dense numbers after
    the last block)."""
    from tpo.algo.networks import init_params

    env = GridNav(load_map("home"), observation=observation)
    tr = Trainer(env, ObjectiveGraph.parse("M>A>G", [5.0, 5.0], objectives=OBJECTIVES),
                 TPOConfig(), 10**5)
    assert tr.actor.onehots == tr.critics.onehots == env.observation_onehots != ()
    plain_actor = dataclasses.replace(tr.actor, onehots=())
    plain_critics = dataclasses.replace(tr.critics, onehots=())
    params = tr.init_params(jax.random.key(3))
    jax.tree.map(np.testing.assert_array_equal, params,
                 init_params(jax.random.key(3), plain_actor, plain_critics, env.obs_shape))
    obs = env.params.obs_table.reshape(-1, env.obs_shape[0])
    for net, plain, p in [(tr.actor, plain_actor, params["actor"]),
                          (tr.critics, plain_critics, params["critics"])]:
        def total(q, module):
            out = module.apply({"params": q}, obs)
            return jnp.sum(jnp.sin(getattr(out, "logits", out)))
        np.testing.assert_allclose(total(p, net), total(p, plain), rtol=1e-5)
        jax.tree.map(lambda a, b: np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-5),
                     jax.grad(total)(p, net), jax.grad(total)(p, plain))
    np.testing.assert_allclose(tr.critics.head(params["critics"], 2, obs),
                               plain_critics.head(params["critics"], 2, obs), rtol=1e-5,
                               atol=1e-6)


@pytest.mark.parametrize("shape", [(7, 16), (16, 16), (16, 3), (3, 2)])
def test_the_orthogonal_initialiser_is_jax_s_bit_for_bit(shape):
    """A kernel's Gaussian draw (in a compiled program) made orthogonal on the host is
    jax.nn.initializers.orthogonal's kernel of the same key, alone and stacked (as
    the critics' heads)."""
    from tpo.algo.networks import gaussian_draw, orthogonal

    key = jax.random.key(3)
    ours = orthogonal(jax.jit(gaussian_draw, static_argnums=1)(key, shape), 0.5)
    np.testing.assert_array_equal(ours, jax.nn.initializers.orthogonal(0.5)(key, shape))
    keys = jax.random.split(key, 4)
    np.testing.assert_array_equal(
        orthogonal(jax.vmap(gaussian_draw, in_axes=(0, None))(keys, shape), 2.0),
        jax.vmap(jax.nn.initializers.orthogonal(2.0), in_axes=(0, None))(keys, shape))


def test_initialisation_runs_no_qr_and_no_callback_in_an_xla_program(small):
    """jaxlib's QR kernel waits for helpers on XLA's pool (two at once on two threads
    deadlock), and a Python callback's argument waits for XLA's threads too (on one
    CPU it hung): the program that draws the parameters holds neither
    (docs/design.md §5). The custom call names the LAPACK routine."""
    from tpo.algo.networks import draw_params

    graph = ObjectiveGraph.parse("M>A>G", 0, objectives=OBJECTIVES)
    trainer = Trainer(small[0], graph, TPOConfig(num_envs=4, num_steps=32), 3 * 4 * 32)
    hlo = draw_params.lower(jax.random.key(0), trainer.actor, trainer.critics,
                            small[0].obs_shape).as_text()
    assert "geqrf" not in hlo and "callback" not in hlo


ONE_CPU_INITS = """
import jax
from tpo.algo import TPOConfig, Trainer
from tpo.envs import GridNav, load_map
from tpo.graph import ObjectiveGraph
env = GridNav(load_map("home"))
trainer = Trainer(env, ObjectiveGraph.parse("M>A>G", [0, 0], objectives=env.objectives),
                  TPOConfig(), 10**6)
for i in range(60):  # five seeds at a time, as a sweep starts
    jax.block_until_ready([trainer.init(jax.random.key(5 * i + s)) for s in range(5)])
print("done")
"""


def test_a_process_on_one_cpu_initialises_runs_without_hanging():
    """Pinned to one CPU, a process that starts runs five at a time (as
    :func:`run_sweep`) finishes. With the QR in a ``jax.pure_callback`` inside the
    initialising program, 2 of 3 such processes hung (its argument's ``np.asarray``
    never returned: docs/design.md §5)."""
    import os
    import subprocess
    import sys

    cpu = min(os.sched_getaffinity(0))
    for _ in range(2):
        done = subprocess.run([sys.executable, "-c", ONE_CPU_INITS], capture_output=True,
                              text=True, timeout=90,
                              preexec_fn=lambda: os.sched_setaffinity(0, {cpu}))
        assert done.stdout.strip() == "done", done.stderr[-3000:]


@pytest.mark.parametrize("constraint", ["penalty", "restriction"])
def test_a_rollout_s_values_equal_the_critics_on_every_true_next_state(constraint):
    """:meth:`Trainer.rollout_values` runs the critics on each observation once and
    on a second ``s_{t+1}`` only after a truncation and at the last step (at most
    ``(T - 1) // max_steps + 2`` a copy): its values equal the critics' on ``obs``
    and on ``final_obs`` wherever a next value counts (``s_{t+1}`` not terminal)."""
    env = GridNav(load_map("small"), random_start=True, max_steps=4)
    graph = ObjectiveGraph.parse("A>M>G", 0, objectives=OBJECTIVES)
    trainer = Trainer(env, graph, TPOConfig(num_envs=16, num_steps=32, constraint=constraint),
                      3 * 16 * 32)
    assert trainer.own_next == 31 // 4 + 2
    state = trainer.init(jax.random.key(0))
    _, rollout, _ = jax.jit(trainer.collect)(state, trainer.slack_array())
    truncated = np.asarray(rollout.done > rollout.terminated)
    assert truncated[:-1].sum(axis=0).min() >= 6  # every copy truncated at least 6 times
    assert np.asarray(rollout.terminated).any()  # and some reached the goal
    value, next_value = jax.jit(trainer.rollout_values)(state, rollout)
    every = trainer.values(state, jnp.stack([rollout.obs, rollout.final_obs]))[..., 0]
    # One float32 critic call on other rows: the same sums, up to their order.
    np.testing.assert_allclose(value, every[0], rtol=0, atol=1e-5)
    counts = np.asarray(rollout.terminated) == 0
    np.testing.assert_allclose(np.asarray(next_value)[counts], np.asarray(every[1])[counts],
                               rtol=0, atol=1e-5)


def test_a_learner_of_one_view_never_reads_the_rest_of_the_observation(small):
    """View 1 of the factored+onehot observation is the cell's one-hot: the first
    layers' weights from the factored numbers start at zero and stay there, so the
    policy and the critics are the same whatever those numbers are."""
    train_env, _ = small
    graph = ObjectiveGraph.parse("M>A>G", [100.0, 0.0], objectives=OBJECTIVES)
    trainer = Trainer(train_env, graph, TPOConfig(num_envs=8, num_steps=32), 8 * 32 * 6)
    hidden = ~trainer.views[1].astype(bool)
    assert trainer.views.shape == (3, train_env.obs_shape[0]) and hidden.sum() == 8 + 13 + 6
    state = trainer.init(jax.random.key(0), view=1)
    state, _ = jax.jit(trainer.run, static_argnums=2)(state, trainer.slack_array(), 3)
    actor = state.params["actor"]["layer_0"]["kernel"]
    critics = state.params["critics"]["heads"]["layer_0"]["kernel"]
    assert not np.asarray(actor)[hidden].any() and not np.asarray(critics)[:, hidden].any()
    assert np.asarray(actor)[~hidden].any()  # the seen part learns
    obs = jnp.asarray(train_env.tabular_observations())
    noise = jax.random.normal(jax.random.key(1), obs.shape) * jnp.asarray(hidden)
    acting = trainer.acting(state, trainer.slack_array())
    np.testing.assert_array_equal(trainer.policy(acting, obs).logits,
                                  trainer.policy(acting, obs + noise).logits)
    np.testing.assert_array_equal(trainer.values(state, obs), trainer.values(state, obs + noise))
