"""Properties of the exact solvers on random TMDPs (hypothesis)."""

import itertools

import numpy as np
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from strategies import SOLVER_SETTINGS, graphs, models
from tpo.errors import InfeasibleError
from tpo.graph import ObjectiveGraph
from tpo.tabular import (
    ATOL,
    evaluate_policy,
    multiplier_bound,
    solve_lagrangian,
    solve_lar,
)


@SOLVER_SETTINGS
@given(models(), graphs())
def test_action_sets_nest_and_the_leaf_policy_stays_inside(model, graph):
    sol = solve_lar(model, graph, relax=True)
    relaxed = np.zeros(model.n_states, bool)
    for states in sol.relaxed.values():
        relaxed[states] = True
    for v in sol.order:
        for w in graph.ancestors(v):
            inside = sol.allowed[v] <= sol.allowed[w]
            assert inside[~relaxed].all(), f"A_{v} not inside A_{w}"
    leaf = sol.allowed[graph.leaf]
    assert leaf[np.arange(model.n_states), sol.policy].all()


@SOLVER_SETTINGS
@given(models(), graphs())
def test_the_leaf_policy_keeps_every_ancestral_constraint(model, graph):
    try:
        sol = solve_lar(model, graph)
    except InfeasibleError:
        assume(False)
    live = ~model.terminal
    s = np.arange(model.n_states)
    for edge in graph.ancestral_edges(graph.leaf):
        loss = sol.values[edge.parent] - sol.q_values[edge.parent][s, sol.policy]
        assert np.all(loss[live] <= edge.slack + ATOL)


def lexicographic_best(model, order):
    """Brute force over all deterministic policies: the lexicographic max of V(s0)."""
    best = None
    for actions in itertools.product(range(model.n_actions), repeat=model.n_states):
        v = evaluate_policy(model, np.array(actions))[model.start]
        key = [v[model.index(n)] for n in order]
        if best is None:
            best = key
            continue
        for new, old in zip(key, best, strict=True):
            if abs(new - old) > 1e-9:
                if new > old:
                    best = key
                break
    return best


@settings(max_examples=40, deadline=None)
@given(models(max_states=5, max_actions=2))
def test_zero_slack_chain_is_the_strict_lexicographic_optimum(model):
    graph = ObjectiveGraph.parse("c>a>d>b", 0)
    sol = solve_lar(model, graph)
    got = [sol.start_policy_values()[n] for n in graph.order]
    assert np.allclose(got, lexicographic_best(model, graph.order), atol=1e-7)


@SOLVER_SETTINGS
@given(models(), graphs())
def test_huge_slack_gives_the_leafs_unconstrained_optimum(model, graph):
    sol = solve_lar(model, graph.with_slack(1e6))
    alone = solve_lar(model, ObjectiveGraph.parse(graph.leaf))
    assert np.allclose(sol.values[graph.leaf], alone.values[graph.leaf], atol=1e-8)
    assert np.allclose(sol.policy_values[graph.leaf], alone.values[graph.leaf], atol=1e-8)


@SOLVER_SETTINGS
@given(models(), graphs(), st.floats(1.5, 4.0))
def test_lagrangian_bellman_equals_lar_above_the_bound(model, graph, factor):
    """Theorem 1: with beta_s above the bound of Prop. 2, Eq. 6 solves the LAR problem."""
    try:
        lar = solve_lar(model, graph)
    except InfeasibleError:
        assume(False)
    beta = {n: factor * multiplier_bound(lar, n) + 1.0 for n in graph.order}
    lag = solve_lagrangian(model, graph, beta)
    for n in graph.order:
        assert np.allclose(lag.values[n], lar.values[n], atol=1e-8), n
    assert lag.policy.tolist() == lar.policy.tolist()
    for n in model.objectives:
        assert np.allclose(lag.policy_values[n], lar.policy_values[n], atol=1e-8)


@SOLVER_SETTINGS
@given(models(), st.sampled_from(["a>b>c>d", "d>c>b>a", "b>a>d>c"]))
def test_chains_are_always_feasible(model, spec):
    assert solve_lar(model, ObjectiveGraph.parse(spec, 0)).feasible
