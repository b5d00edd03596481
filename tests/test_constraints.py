"""The constraint terms of a phase (tpo.algo.constraints), each against numbers
worked out by hand: ``A>G``, phase 0 the avoid root and phase 1 the goal leaf
with one constraint on the avoid head; reward columns (avoid, goal); values 0, so
each head's one-step advantage is its reward; gamma = lambda = 0.5 (GAE's trace
0.25)."""

import jax.numpy as jnp
import numpy as np
import pytest

from tpo.algo.config import TPOConfig
from tpo.algo.constraints import (
    ConstraintTerms,
    lagrangian_terms,
    loose_tolerance,
    penalty,
    trace_decay,
)
from tpo.algo.phases import Problem
from tpo.envs import OBJECTIVES
from tpo.graph import ObjectiveGraph


def terms(**changes) -> ConstraintTerms:
    f32 = np.float32
    base = dict(reward=np.array([0, 1]), head=np.array([0]), slack_index=np.array([0]),
                weights=np.array([[0.0], [1.0]], f32), beta=np.full(2, 10.0, f32),
                margin=np.zeros(1, f32), tolerance=np.zeros(1, f32), loose=np.zeros(1, bool),
                telescoped=np.zeros(1, bool), dead_zone=np.zeros(1, f32),
                tie=np.zeros((2, 2), f32), tie_bound=np.zeros(2, f32), tie_critic="ancestors",
                advantage="immediate", gamma=0.5, lam=0.5, second_tolerance=0.1,
                second_floor=np.full(1, 0.02, f32))
    return ConstraintTerms(**{**base, **changes})


def charged(t: ConstraintTerms, avoid_advantages, slack, loose_tol=0.0, phase=1):
    adv = jnp.stack([jnp.asarray(avoid_advantages, jnp.float32),
                     jnp.zeros(len(avoid_advantages))], -1)
    return np.asarray(penalty(t, adv, jnp.array([slack], jnp.float32), jnp.int32(phase),
                              jnp.array([loose_tol], jnp.float32)))


def test_eq_10_charges_the_violation_beyond_the_slack_to_the_phases_that_keep_it():
    # C = max(0, -A - eta): slack 1
    np.testing.assert_allclose(charged(terms(), [-3.0, -0.5, 1.0], 1.0), [2.0, 0.0, 0.0])
    # the root's own phase keeps no constraint
    np.testing.assert_allclose(charged(terms(), [-3.0, -0.5, 1.0], 1.0, phase=0), [0, 0, 0])


def test_the_margin_charges_from_below_the_slack_at_most_half_of_it():
    t = terms(margin=np.array([0.3], np.float32))
    np.testing.assert_allclose(charged(t, [-3.0, -0.5, -0.8], 1.0), [2.3, 0.0, 0.1], atol=1e-6)
    # slack 0.4: the margin is min(0.3, 0.2), so it counts from 0.2
    np.testing.assert_allclose(charged(t, [-0.5], 0.4), [0.3], atol=1e-6)
    np.testing.assert_allclose(charged(t, [-0.5], 0.0), [0.5], atol=1e-6)  # none at 0


def test_a_loose_constraint_at_zero_slack_counts_from_its_tolerance():
    t = terms(loose=np.array([True]))
    np.testing.assert_allclose(charged(t, [-1.0, -0.3, 0.2], 0.0, 0.4), [0.6, 0.0, 0.0],
                               atol=1e-6)
    np.testing.assert_allclose(charged(t, [-1.0], 0.5, 0.4), [0.5], atol=1e-6)  # slack > 0


def test_a_telescoped_constraint_at_zero_slack_charges_the_advantage_itself():
    t = terms(telescoped=np.array([True]))
    np.testing.assert_allclose(charged(t, [-1.0, 0.3], 0.0), [1.0, -0.3], atol=1e-6)
    np.testing.assert_allclose(charged(t, [-1.0, 0.3], 0.5), [0.5, 0.0], atol=1e-6)


def test_the_dead_zone_soft_thresholds_a_telescoped_advantage():
    t = terms(telescoped=np.array([True]), dead_zone=np.array([0.5], np.float32))
    np.testing.assert_allclose(charged(t, [-0.25, 0.3, -0.9, 0.8], 0.0), [0.0, 0.0, 0.4, -0.3],
                               atol=1e-6)


def run(t: ConstraintTerms, avoid, goal, slack=0.5, explore=(0.0, 0.0), design=0):
    """The goal phase's (advantage, target, penalty) on a 2-step rollout of one env."""
    reward = jnp.asarray(np.stack([avoid, goal], -1)[:, None, :], jnp.float32)  # [T, E, k]
    zeros = jnp.zeros((2, 1, 2))
    flags = jnp.zeros((2, 1))
    out = lagrangian_terms(t, jnp.int32(1), jnp.array([slack], jnp.float32), reward, zeros,
                           zeros, flags, flags, jnp.asarray(explore, jnp.float32)[:, None],
                           jnp.zeros(1), trace_decay(t, jnp.int32(design)))
    return [np.asarray(x)[:, 0] for x in out]


@pytest.mark.parametrize(("form", "advantage", "target"), [
    # GAE of the goal rewards (1, 2): (1 + 0.25 * 2, 2) = (1.5, 2); the penalty (0, 1.5)
    ("immediate", [1.5, 2.0 - 15.0], [1.5, 2.0]),  # on its own action
    ("traced", [1.5 - 10 * 0.375, -13.0], [1.5, 2.0]),  # summed back by 0.25
    ("penalized", [-2.25, -13.0], [-2.25, -13.0])])  # GAE of r - beta C: the critic's too
def test_the_penalty_enters_the_advantage_in_each_form(form, advantage, target):
    adv, tgt, pen = run(terms(advantage=form), [0.0, -2.0], [1.0, 2.0])
    np.testing.assert_allclose(pen, [0.0, 1.5], atol=1e-6)
    np.testing.assert_allclose(adv, advantage, atol=1e-5)
    np.testing.assert_allclose(tgt, target, atol=1e-5)


def test_the_second_design_traces_the_penalty_by_gamma_and_counts_from_the_spread():
    adv, _, _ = run(terms(advantage="traced"), [0.0, -2.0], [1.0, 2.0], design=1)
    np.testing.assert_allclose(adv, [1.5 - 10 * 0.75, -13.0], atol=1e-5)  # 0.5 * 1.5 back
    t = terms(tolerance=np.array([0.4], np.float32))
    np.testing.assert_allclose(loose_tolerance(t, jnp.int32(0), jnp.array([3.0, 1.0])), [0.4])
    np.testing.assert_allclose(loose_tolerance(t, jnp.int32(1), jnp.array([3.0, 1.0])), [0.3],
                               rtol=1e-6)  # 0.1 of the avoid head's spread 3
    np.testing.assert_allclose(loose_tolerance(t, jnp.int32(1), jnp.array([0.1, 1.0])), [0.02],
                               rtol=1e-6)  # at least the floor
    wide = terms(second_floor=np.array([2.0], np.float32))  # a range of 200: 0.01 of it
    np.testing.assert_allclose(loose_tolerance(wide, jnp.int32(1), jnp.array([3.0, 1.0])),
                               [2.0])


def test_the_tie_break_adds_the_ancestors_advantages_bounded_and_traced():
    # tie 0.1 on the avoid head, bound 0.05: steps clip(0.1 (-0.3, 0.2)) = (-0.03, 0.02),
    # traced by 0.25: (-0.025, 0.02); slack 100 charges nothing
    tie = np.array([[0, 0], [0.1, 0]], np.float32)
    on = terms(tie=tie, tie_bound=np.array([0, 0.05], np.float32))
    adv, tgt, _ = run(on, [-0.3, 0.2], [1.0, 2.0], slack=100.0)
    np.testing.assert_allclose(adv, [1.5 - 0.025, 2.02], atol=1e-6)
    np.testing.assert_allclose(tgt, [1.5, 2.0], atol=1e-6)  # the critic's own returns
    big = run(on, [-9.0, 0.0], [1.0, 2.0], slack=100.0)[0]
    np.testing.assert_allclose(big, [1.5 - 0.05, 2.0], atol=1e-6)  # bounded by 0.05


def test_the_leaf_critic_values_the_tie_break_in_its_reward_and_target():
    # the goal rewards gain 0.1 x avoid's: (0.97, 2.02), GAE (0.97 + 0.25 * 2.02, 2.02)
    tie = np.array([[0, 0], [0.1, 0]], np.float32)
    adv, tgt, _ = run(terms(tie=tie, tie_critic="leaf"), [-0.3, 0.2], [1.0, 2.0], slack=100.0)
    np.testing.assert_allclose(adv, [1.475, 2.02], atol=1e-6)
    np.testing.assert_allclose(tgt, [1.475, 2.02], atol=1e-6)


def test_an_exploring_step_cuts_the_trace_before_it():
    adv, _, _ = run(terms(), [0.0, 0.0], [1.0, 2.0], explore=(0.0, 1.0))
    np.testing.assert_allclose(adv, [1.0, 2.0], atol=1e-6)


def test_the_restriction_form_pays_no_penalty_and_telescopes_nothing():
    graph = ObjectiveGraph.parse("A>G", 0.0, objectives=OBJECTIVES)
    problem = Problem.build(graph, OBJECTIVES, TPOConfig())
    low, high = np.array([-1.0, -2.0, -1.0]), np.array([-1.0, 0.0, 1.0])
    kept = ConstraintTerms.build(problem, TPOConfig(), low, high, penalized=False)
    assert not kept.weights.any() and not kept.telescoped.any()
    paid = ConstraintTerms.build(problem, TPOConfig(), low, high)
    assert paid.weights.tolist() == [[0.0], [1.0]] and paid.telescoped.tolist() == [True]
    assert paid.margin.tolist() == pytest.approx([0.3])  # 0.15 of avoid's range 2
    assert paid.tolerance.tolist() == pytest.approx([0.4])  # 0.2 of it
    assert paid.second_floor.tolist() == pytest.approx([0.02])  # 0.01 of it
