"""Exact policy evaluation, visitation and the exact policy gradient (Prop. 3)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from strategies import models
from tpo.errors import ModelError
from tpo.graph import ObjectiveGraph
from tpo.tabular import (
    TabularTMDP,
    discounted_visitation,
    evaluate_policy,
    multiplier_bound,
    policy_gradient,
    q_values,
    softmax,
    solve_lar,
)
from tpo.tabular.bellman import penalty


def dense(model: TabularTMDP) -> np.ndarray:
    """``T[s, a, s']`` rebuilt from the successor lists (terminal rows zeroed)."""
    t = np.zeros((model.n_states, model.n_actions, model.n_states))
    for s, a, b in np.ndindex(model.successors.shape):
        t[s, a, model.successors[s, a, b]] += model.probs[s, a, b]
    t[model.terminal] = 0
    return t


def random_policy(model, seed):
    return softmax(np.random.default_rng(seed).normal(size=(model.n_states, model.n_actions)))


@settings(max_examples=40, deadline=None)
@given(models(), st.integers(0, 1000))
def test_evaluation_equals_the_dense_inverse(model, seed):
    pi = random_policy(model, seed)
    p = np.einsum("sa,sat->st", pi, dense(model))
    r = np.einsum("sa,sak->sk", pi, model.rewards)
    expected = np.linalg.solve(np.eye(model.n_states) - model.gamma * p, r)
    assert np.allclose(evaluate_policy(model, pi), expected, atol=1e-10)


@settings(max_examples=40, deadline=None)
@given(models(), st.integers(0, 1000))
def test_visitation_sums_to_the_discounted_horizon_without_terminals(model, seed):
    pi = random_policy(model, seed)
    d = discounted_visitation(model, pi)
    assert np.all(d >= -1e-12)
    if not model.terminal.any():
        assert d.sum() == pytest.approx(1 / (1 - model.gamma))


@settings(max_examples=30, deadline=None)
@given(models(), st.integers(0, 1000))
def test_policy_gradient_equals_finite_differences(model, seed):
    logits = np.random.default_rng(seed).normal(size=(model.n_states, model.n_actions))
    grad = policy_gradient(model, logits)
    eps = 1e-6
    numeric = np.zeros_like(grad)
    for s, a in np.ndindex(logits.shape):
        step = np.zeros_like(logits)
        step[s, a] = eps
        hi = evaluate_policy(model, softmax(logits + step))[model.start]
        lo = evaluate_policy(model, softmax(logits - step))[model.start]
        numeric[:, s, a] = (hi - lo) / (2 * eps)
    assert np.allclose(grad, numeric, atol=1e-6)


def test_lagrangian_gradient_equals_finite_differences():
    """Prop. 3 with the penalised reward R_i - beta C of Eq. 6."""
    model = _fixed_model()
    sol = solve_lar(model, ObjectiveGraph.parse("a>b>c>d", 0.5))
    beta = multiplier_bound(sol, "d") + 1.0
    reward = model.rewards[:, :, model.index("d")] - beta[:, None] * penalty(
        model, sol.graph.ancestral_edges("d"), sol.values)
    logits = np.random.default_rng(3).normal(size=(model.n_states, model.n_actions))
    grad = policy_gradient(model, logits, reward)[0]
    eps = 1e-6
    for s, a in np.ndindex(logits.shape):
        step = np.zeros_like(logits)
        step[s, a] = eps
        hi = evaluate_policy(model, softmax(logits + step), reward)[model.start, 0]
        lo = evaluate_policy(model, softmax(logits - step), reward)[model.start, 0]
        assert grad[s, a] == pytest.approx((hi - lo) / (2 * eps), abs=1e-6)


def _fixed_model() -> TabularTMDP:
    rng = np.random.default_rng(0)
    n, a = 5, 3
    succ = rng.integers(0, n, size=(n, a, 2))
    probs = np.full((n, a, 2), 0.5)
    rewards = rng.integers(-2, 3, size=(n, a, 4)).astype(float)
    return TabularTMDP(succ, probs, rewards, ("a", "b", "c", "d"), gamma=0.9)


def test_q_values_of_v_pi_average_to_v_pi():
    model = _fixed_model()
    pi = random_policy(model, 1)
    v = evaluate_policy(model, pi)
    q = q_values(model, v)
    assert np.allclose(np.einsum("sa,sak->sk", pi, q), v)


def test_deterministic_and_one_hot_policies_agree():
    model = _fixed_model()
    actions = np.array([0, 2, 1, 1, 0])
    assert np.allclose(evaluate_policy(model, actions),
                       evaluate_policy(model, np.eye(3)[actions]))


# ------------------------------------------------------------ model validation
def _parts():
    succ = np.array([[[1], [0]], [[1], [1]]])
    probs = np.ones((2, 2, 1))
    rewards = np.zeros((2, 2, 2))
    return dict(successors=succ, probs=probs, rewards=rewards, objectives=("x", "y"),
                gamma=0.9, start=0, terminal=np.array([False, True]))


def _with(**changes):
    parts = _parts()
    parts.update(changes)
    return parts


@pytest.mark.parametrize(
    ("parts", "message"),
    [
        (_with(probs=np.full((2, 2, 1), 0.5)), "state 0, action 0 sum to 0.5, not 1"),
        (_with(successors=np.array([[[1, 0], [0, 0]], [[1, 1], [1, 1]]]),
               probs=np.array([[[1.5, -0.5], [1, 0]], [[1, 0], [1, 0]]])), "finite and >= 0"),
        (_with(successors=np.array([[[2], [0]], [[1], [1]]])), "successor index out of range"),
        (_with(successors=np.array([[[1.0], [0.0]], [[1.0], [1.0]]])), "must be integers"),
        (_with(rewards=np.full((2, 2, 2), np.nan)), "non-finite reward at state 0, action 0"),
        (_with(rewards=np.zeros((2, 2, 3))), "3 column(s) but 2 objective name(s)"),
        (_with(rewards=np.zeros((3, 2, 2))), "rewards must be [S=2, A=2, k]"),
        (_with(probs=np.ones((2, 2, 2))), "probs shape"),
        (_with(gamma=1.0), "gamma must be a number in [0, 1), got 1.0"),
        (_with(gamma=-0.1), "gamma must be a number in [0, 1)"),
        (_with(start=2), "start state must be an index in [0, 2), got 2"),
        (_with(objectives=("x", "x")), "unique non-empty"),
        (_with(terminal=np.array([0, 1])), "terminal must be a bool array"),
        (_with(rewards=np.ones((2, 2, 2))), "state 1 has a non-zero reward"),
        (_with(successors=np.zeros((2, 2))), "successors must be [S, A, B]"),
    ],
)
def test_bad_models_are_rejected_with_a_clear_message(parts, message):
    with pytest.raises(ModelError) as err:
        TabularTMDP(**parts)
    assert message in str(err.value)


def test_bad_policies_are_rejected():
    model = TabularTMDP(**_parts())
    with pytest.raises(ModelError, match="one row per state"):
        evaluate_policy(model, np.array([0]))
    with pytest.raises(ModelError, match="action indices"):
        evaluate_policy(model, np.array([0, 2]))
    with pytest.raises(ModelError, match="summing to 1"):
        evaluate_policy(model, np.full((2, 2), 0.7))


def test_a_million_state_grid_is_stored_compactly():
    n = 1000
    cells = np.arange(n * n)
    r, c = np.divmod(cells, n)
    succ = np.stack([np.clip(r - 1, 0, n - 1) * n + c, np.clip(r + 1, 0, n - 1) * n + c,
                     r * n + np.clip(c - 1, 0, n - 1), r * n + np.clip(c + 1, 0, n - 1)],
                    axis=1)[:, :, None]
    model = TabularTMDP(succ, np.ones(succ.shape), np.zeros((n * n, 4, 3)),
                        ("goal", "avoid", "monitor"), gamma=0.99)
    size = model.successors.nbytes + model.probs.nbytes + model.rewards.nbytes
    assert size < 150e6  # a dense S x A x S array would need 32 TB
    assert model.deterministic
