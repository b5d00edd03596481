"""The tie rule (lexicographic completion) and the LAR-correct criterion on TMDPs
worked out by hand, and as properties of random TMDPs."""

import numpy as np
import pytest
from hypothesis import given

from strategies import SOLVER_SETTINGS, graphs, models
from tpo.graph import ObjectiveGraph
from tpo.tabular import Judge, TabularTMDP, solve_lagrangian, solve_lar
from tpo.tabular.judge import ABS_TOL, value_ranges


def detour_model() -> TabularTMDP:
    """States s0, s1, s2 and an end state; objectives (a, b); gamma = 1/2.

    s0: action 0 -> s1, action 1 -> s2 (no reward)
    s1: action 0 -> end, a = 10, b = -1;  action 1 -> end, a = 0, b = 0
    s2: either action -> end, a = 5, b = 0
    """
    t = np.zeros((4, 2, 4))
    r = np.zeros((4, 2, 2))
    t[0, 0, 1] = t[0, 1, 2] = 1
    t[1, :, 3] = t[2, :, 3] = t[3, :, 3] = 1
    r[1, 0], r[2, :] = (10, -1), (5, 0)
    return TabularTMDP.from_dense(t, r, ("a", "b"), gamma=0.5,
                                  terminal=np.array([0, 0, 0, 1], bool))


def test_an_indifferent_leaf_gives_its_freedom_to_the_root_over_whole_policies():
    # With slack 100 on a > b, b may do anything; b's optimum is 0 and both actions at s0
    # reach it (s1 then action 1, or s2). The per-state tie-break by Q*_a would go to s1
    # (Q*_a = 5 against 2.5), where b's own choice then leaves a nothing. The completion
    # optimises a over b's optimal policies: s2, a = 5/2.
    sol = solve_lar(detour_model(), ObjectiveGraph.parse("a>b", 100.0))
    assert sol.policy[:3].tolist() == [1, 1, 0]
    assert sol.start_policy_values() == pytest.approx({"a": 2.5, "b": 0.0})
    judge = Judge(sol)
    assert judge.floors == pytest.approx({"a": 0.0})  # b's admissible policies: a >= 0
    greedy_tie_break = judge(np.array([0, 1, 0, 0]))  # s0 -> s1, then b's best
    assert greedy_tie_break.lar_correct and greedy_tie_break.strict
    assert not greedy_tie_break.same_values  # a = 0 against the completion's 2.5
    assert greedy_tie_break.values == pytest.approx({"a": 0.0, "b": 0.0})


def test_an_ancestor_below_its_floor_is_not_lar_correct():
    # Slack 0: b may only use a's optimal actions (s0 -> s1, then a = 10): floor_a = 5.
    # Going to s2 is better for b (0 against -1/2) and costs a half its value.
    sol = solve_lar(detour_model(), ObjectiveGraph.parse("a>b", 0.0))
    judge = Judge(sol)
    assert judge.floors == pytest.approx({"a": 5.0}) and judge.solution.policy[0] == 0
    verdict = judge(np.array([1, 0, 0, 0]))
    assert verdict.values == pytest.approx({"a": 2.5, "b": 0.0})
    assert not verdict.lar_correct and not verdict.strict and not verdict.same_values
    assert verdict.outside == (0,)
    own = judge(sol.policy)
    assert own.lar_correct and own.strict and own.same_values and own.outside == ()


def test_a_small_step_outside_the_admissible_set_is_correct_but_not_strict():
    # A bandit at slack 0: action 0 (a = 1, b = 0) is a's best, action 1 (0.9, 0.2) loses
    # 0.1 of a; within the maps' absolute tolerance 0.5 on every value, but outside A_b.
    t = np.zeros((2, 2, 2))
    t[:, :, 1] = 1
    r = np.zeros((2, 2, 2))
    r[0] = [(1.0, 0.0), (0.9, 0.2)]
    model = TabularTMDP.from_dense(t, r, ("a", "b"), gamma=0.9,
                                   terminal=np.array([0, 1], bool))
    sol = solve_lar(model, ObjectiveGraph.parse("a>b", 0.0))
    verdict = Judge(sol, absolute=ABS_TOL)(np.array([1, 0]))
    assert verdict.lar_correct and verdict.same_values
    assert not verdict.strict and verdict.outside == (0,)
    # Scale-free (the default): a's value range is 1 - 0.9 = 0.1, so its tolerance is
    # max(0.02 * 1, 0.0025 * 0.1) = 0.02, and losing 0.1 of a is not LAR-correct.
    judge = Judge(sol)
    assert judge.absolute == pytest.approx({"a": 0.00025, "b": 0.0005})
    assert judge.tolerance("a", 1.0) == pytest.approx(0.02)
    assert not judge(np.array([1, 0])).lar_correct


def test_value_ranges_are_each_objectives_best_less_its_worst_at_the_start():
    # detour: a is 5 by s1 and action 0, 0 by s1 and action 1; b is 0 at best and
    # -1/2 by s1 and action 0
    assert value_ranges(detour_model()) == pytest.approx({"a": 5.0, "b": 0.5})


@SOLVER_SETTINGS
@given(models(), graphs())
def test_the_solvers_own_policy_passes_all_three_and_theorem_1_keeps_it(model, graph):
    sol = solve_lar(model, graph, relax=True)
    verdict = Judge(sol)(sol.policy)
    assert verdict.lar_correct and verdict.strict and verdict.same_values
    leaf = sol.allowed[graph.leaf]
    q = sol.q_values[graph.leaf]
    best = np.where(leaf, q, -np.inf).max(axis=1)
    s = np.arange(model.n_states)
    live = ~model.terminal
    assert np.all(q[s, sol.policy][live] >= best[live] - 1e-7)  # leaf-optimal everywhere
    if sol.feasible:
        lag = solve_lagrangian(model, graph, beta=1e6)
        np.testing.assert_array_equal(lag.policy[live], sol.policy[live])
