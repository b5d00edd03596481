"""Exact solvers on tiny TMDPs whose answers are worked out by hand in the comments."""

import numpy as np
import pytest

from tpo.errors import InfeasibleError
from tpo.graph import ObjectiveGraph
from tpo.tabular import (
    TabularTMDP,
    evaluate_policy,
    multiplier_bound,
    solve_lagrangian,
    solve_lar,
)


def two_step_chain_model() -> TabularTMDP:
    """States 0 (start), 1, 2 (terminal); objectives (a, b); gamma = 1/2.

    s0: action 0 -> end with r = (1, 0);  action 1 -> s1 with r = (0, 1)
    s1: action 0 -> end with r = (1, 0);  action 1 -> end with r = (0, 2)
    """
    t = np.zeros((3, 2, 3))
    r = np.zeros((3, 2, 2))
    t[0, 0, 2], r[0, 0] = 1, (1, 0)
    t[0, 1, 1], r[0, 1] = 1, (0, 1)
    t[1, 0, 2], r[1, 0] = 1, (1, 0)
    t[1, 1, 2], r[1, 1] = 1, (0, 2)
    t[2, :, 2] = 1
    return TabularTMDP.from_dense(t, r, ("a", "b"), gamma=0.5, terminal=np.array([0, 0, 1], bool))


def bandit(rewards: list[tuple[float, ...]], names: tuple[str, ...]) -> TabularTMDP:
    """One decision at s0, every action ends the episode (s1 is terminal)."""
    n = len(rewards)
    t = np.zeros((2, n, 2))
    t[:, :, 1] = 1
    r = np.zeros((2, n, len(names)))
    r[0] = rewards
    return TabularTMDP.from_dense(t, r, names, gamma=0.9, terminal=np.array([0, 1], bool))


# ----------------------------------------------------------------------- chain
# V*_a: Q_a(s1) = (1, 0) so V_a(s1) = 1; Q_a(s0) = (1, 0 + 1/2 * 1) so V_a(s0) = 1.
@pytest.mark.parametrize(
    ("eta", "policy", "v_b", "pi_values"),
    [
        # eta = 0: only a's best actions remain: V*_b = 0 and the policy ends at once.
        (0.0, [0, 0], 0.0, {"a": 1.0, "b": 0.0}),
        # eta = 0.6: at s0 action 1 loses 1 - 1/2 = 0.5 <= 0.6 of a's value; at s1 action 1
        # loses 1 > 0.6. V*_b(s1) = 0, Q_b(s0, 1) = 1 + 0 = 1. a gets 0 + 1/2 * 1 = 0.5.
        (0.6, [1, 0], 1.0, {"a": 0.5, "b": 1.0}),
        # eta = 1: everything allowed; V*_b(s1) = 2, V*_b(s0) = 1 + 1/2 * 2 = 2 and a gets 0:
        # local slack accumulates (1 at s1 discounted by 1/2, plus 1/2 at s0).
        (1.0, [1, 1], 2.0, {"a": 0.0, "b": 2.0}),
    ],
)
def test_chain_by_hand(eta, policy, v_b, pi_values):
    sol = solve_lar(two_step_chain_model(), ObjectiveGraph.parse("a>b", eta))
    assert sol.values["a"][:2] == pytest.approx([1.0, 1.0])
    assert sol.values["b"][0] == pytest.approx(v_b)
    assert sol.policy[:2].tolist() == policy
    assert sol.start_policy_values() == pytest.approx(pi_values)
    assert sol.feasible and sol.order == ("a", "b")


def test_chain_multiplier_bound_by_hand():
    # eta = 0. s0: action 1 violates by 1 - 1/2 = 0.5 and gains Q_b = 1 over V*_b = 0 -> 2.
    # s1: action 1 violates by 1 and gains 2 over 0 -> 2. Terminal state: 0.
    sol = solve_lar(two_step_chain_model(), ObjectiveGraph.parse("a>b", 0))
    assert multiplier_bound(sol, "b") == pytest.approx([2.0, 2.0, 0.0])
    # eta = 0.6: only s1's action 1 violates, by 1 - 0.6 = 0.4, gaining 2 -> 5.
    sol = solve_lar(two_step_chain_model(), ObjectiveGraph.parse("a>b", 0.6))
    assert multiplier_bound(sol, "b") == pytest.approx([0.0, 5.0, 0.0])


def test_multiplier_below_the_bound_lets_a_violating_action_win():
    model = two_step_chain_model()
    graph = ObjectiveGraph.parse("a>b", 0)
    lar = solve_lar(model, graph)
    bound = multiplier_bound(lar, "b")  # [2, 2, 0]
    above = solve_lagrangian(model, graph, {"b": bound * 1.5 + 0.1})
    assert above.policy.tolist() == lar.policy.tolist()
    assert above.start_values() == pytest.approx(lar.start_values())
    # beta = 0.2: at s1 action 1 scores 2 - 0.2 * 1 = 1.8 > 0 and at s0 action 1 scores
    # 1 - 0.2 * 0.5 + 1/2 * 1.8 = 1.8 > 0: both violate a's zero slack.
    below = solve_lagrangian(model, graph, {"b": bound / 10})
    assert below.policy[:2].tolist() == [1, 1]
    assert below.values["b"][0] == pytest.approx(1.8)
    q_a = lar.q_values["a"]
    assert lar.values["a"][0] - q_a[0, below.policy[0]] > 0  # the constraint is violated
    assert below.start_policy_values()["a"] == pytest.approx(0.0)


# ------------------------------------------------------------------------- fan
FAN_REWARDS = [(1, 0, 0), (0, 1, 1), (0.6, 0.6, 2)]  # (a, b, c) per action


@pytest.mark.parametrize(
    ("slack", "action", "pi_values"),
    [
        # a>c at 0.4 and b>c at 0.4: action 2 loses 0.4 of each parent: allowed, best for c.
        ((0.4, 0.4), 2, (0.6, 0.6, 2.0)),
        # b>c at 0 forces action 1 (b's best); it loses 1 <= 1 of a.
        ((1.0, 0.0), 1, (0.0, 1.0, 1.0)),
        ((0.0, 1.0), 0, (1.0, 0.0, 0.0)),
        ((5.0, 5.0), 2, (0.6, 0.6, 2.0)),
    ],
)
def test_fan_by_hand(slack, action, pi_values):
    model = bandit(FAN_REWARDS, ("a", "b", "c"))
    sol = solve_lar(model, ObjectiveGraph.parse("a>c, b>c", list(slack)))
    assert sol.order == ("a", "b", "c")
    assert sol.start_values()["a"] == pytest.approx(1.0)
    assert sol.start_values()["b"] == pytest.approx(1.0)
    assert sol.policy[0] == action
    assert list(sol.start_policy_values().values()) == pytest.approx(list(pi_values))


def test_fan_at_zero_slack_is_infeasible_and_relaxes_to_least_violation():
    model = bandit(FAN_REWARDS, ("a", "b", "c"))
    graph = ObjectiveGraph.parse("a>c, b>c", 0)
    with pytest.raises(InfeasibleError) as err:
        solve_lar(model, graph)
    assert err.value.objective == "c" and err.value.states == [0]
    assert "objective 'c'" in str(err.value)
    # Total violations: action 0 -> 0 + 1, action 1 -> 1 + 0, action 2 -> 0.4 + 0.4.
    sol = solve_lar(model, graph, relax=True)
    assert not sol.feasible
    assert sol.relaxed["c"].tolist() == [0]
    assert sol.policy[0] == 2
    assert sol.summary()["relaxed_states"] == {"c": 1}


# --------------------------------------------------------------------- diamond
DIAMOND_REWARDS = [(2, 0, 0, 0), (2, 1, 0, 0), (2, 0, 1, 0), (1, 1, 1, 3), (2, 1, 1, 1)]
DIAMOND = "a>b, a>c, b>d, c>d"


@pytest.mark.parametrize(
    ("slack", "action", "v_star"),
    [
        # All zero: A_a = {0,1,2,4}; A_b = {1,4}; A_c = {2,4}; A_d = {4}.
        ((0, 0, 0, 0), 4, (2, 1, 1, 1)),
        # a's edges at 1 admit action 3 for b and c; b, c at 0 keep {1,3,4} ∩ {2,3,4} = {3,4}.
        ((1, 1, 0, 0), 3, (2, 1, 1, 3)),
        # Zero slack at the top binds whatever the lower edges allow.
        ((0, 0, 5, 5), 4, (2, 1, 1, 1)),
    ],
)
def test_diamond_by_hand(slack, action, v_star):
    model = bandit(DIAMOND_REWARDS, ("a", "b", "c", "d"))
    sol = solve_lar(model, ObjectiveGraph.parse(DIAMOND, list(slack)))
    assert sol.policy[0] == action
    assert list(sol.start_values().values()) == pytest.approx(list(v_star))


def test_diamond_action_sets_nest_by_hand():
    model = bandit(DIAMOND_REWARDS, ("a", "b", "c", "d"))
    sol = solve_lar(model, ObjectiveGraph.parse(DIAMOND, 0))
    sets = {n: np.flatnonzero(sol.allowed[n][0]).tolist() for n in sol.order}
    # A_a is every action (a is a root); b may use a's best actions {0,1,2,4}, and so on.
    assert sets == {"a": [0, 1, 2, 3, 4], "b": [0, 1, 2, 4], "c": [0, 1, 2, 4], "d": [4]}


# -------------------------------------------------------------------- tie rule
def test_indifferent_leaf_breaks_ties_by_ancestors_then_lowest_index():
    # b is indifferent (all zeros); with slack 10 on a>b every action is allowed.
    # Ties go to a's best action (2), not to the lowest index.
    model = bandit([(0, 0), (1, 0), (3, 0), (3, 0)], ("a", "b"))
    sol = solve_lar(model, ObjectiveGraph.parse("a>b", 10))
    assert sol.policy[0] == 2  # actions 2 and 3 tie on a too: lowest index
    assert sol.start_policy_values() == pytest.approx({"a": 3.0, "b": 0.0})


def test_tie_rule_uses_roots_first():
    # Chain a>b>c with big slack: c and b indifferent among actions 0..2; a prefers 1 or 2,
    # b prefers 2 among those. Roots first: a narrows to {1, 2}, then b picks 2.
    model = bandit([(0, 5, 0), (1, 0, 0), (1, 1, 0)], ("a", "b", "c"))
    sol = solve_lar(model, ObjectiveGraph.parse("a>b>c", 100))
    assert sol.policy[0] == 2


def test_policy_values_equal_exact_evaluation():
    model = two_step_chain_model()
    sol = solve_lar(model, ObjectiveGraph.parse("a>b", 0.6))
    values = evaluate_policy(model, sol.policy)
    assert values[:, 0] == pytest.approx(sol.policy_values["a"])
    assert values[:, 1] == pytest.approx(sol.policy_values["b"])
