"""The Lagrangian Bellman optimality equation (paper Eq. 6) and its multiplier bound (Eq. 7).

For each objective ``i`` in topological order::

    V_i(s) = max_a  R_i(s, a) - beta_s sum_{(w,v) in E_i} C_wv(s, a) + gamma E[V_i(s')]
    C_wv(s, a) = max(0, V_w(s) - Q_w(s, a) - eta_wv)

an *unconstrained* Bellman equation. Theorem 1: with ``beta_s`` above the
bound of Prop. 2 its greedy solution is LAR's.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from tpo.errors import TPOError
from tpo.graph import ObjectiveGraph, resolve_name
from tpo.tabular.bellman import ATOL, penalty, restricted_value_iteration
from tpo.tabular.evaluation import evaluate_policy
from tpo.tabular.lar import LARSolution, Solution, leaf_policy
from tpo.tabular.model import TabularTMDP

BetaLike = float | Mapping[str, float | np.ndarray]


@dataclass(frozen=True, eq=False)
class LagrangianSolution(Solution):
    """A solution of Eq. 6. ``values``/``q_values`` are the Lagrangian (penalised)
    ones, bold **V**, **Q** in the paper; ``beta`` the multipliers ``[S]`` used."""

    beta: dict[str, np.ndarray] = field(default_factory=dict)


def multiplier_bound(solution: LARSolution, objective: str) -> np.ndarray:
    """The lower bound of Prop. 2 (Eq. 7) on ``beta_s`` for ``objective``, ``[S]``::

        beta_s >= max_a (Q_i(s, a) - Q_i(s, a*)) / sum_{E_i} C_wv(s, a)   over a with C > 0

    with ``Q_i`` the one-step values of the constrained optimum ``V*_i`` and ``a*``
    the best admissible action (``Q_i(s, a*) = V*_i(s)``); 0 where nothing violates.
    """
    model, graph = solution.model, solution.graph
    name = resolve_name(objective, graph.objectives)
    pen = penalty(model, graph.ancestral_edges(name), solution.values)
    gain = solution.q_values[name] - solution.values[name][:, None]
    ratio = np.where(pen > 0, gain / np.where(pen > 0, pen, 1.0), 0.0)
    return np.maximum(ratio.max(axis=1), 0.0)


def solve_lagrangian(model: TabularTMDP, graph: ObjectiveGraph, beta: BetaLike,
                     *, atol: float = ATOL) -> LagrangianSolution:
    """Solve Eq. 6 for every objective in topological order.

    The penalty of objective ``i`` uses its ancestors' Lagrangian values from
    this same solve, so the solver is self-contained.

    Args:
        model, graph: the problem.
        beta: one multiplier for every objective and state, or a mapping from
            objective name to a number or a per-state array ``[S]`` (roots need none).
        atol: tolerance of ties (and of zero violation).
    """
    graph = graph.bind(model.objectives)
    everything = np.ones((model.n_states, model.n_actions), bool)
    values: dict[str, np.ndarray] = {}
    q_values: dict[str, np.ndarray] = {}
    betas: dict[str, np.ndarray] = {}
    for name in graph.order:
        edges = graph.ancestral_edges(name)
        b = _beta_for(beta, name, model.n_states) if edges else np.zeros(model.n_states)
        reward = model.rewards[:, :, model.index(name)] - b[:, None] * penalty(
            model, edges, values, atol)
        values[name], q_values[name], _ = restricted_value_iteration(model, reward, everything)
        betas[name] = b
    policy = leaf_policy(model, graph, q_values[graph.leaf], everything, atol)
    exact = evaluate_policy(model, policy)
    return LagrangianSolution(
        model, graph, values, q_values, policy,
        {n: exact[:, i] for i, n in enumerate(model.objectives)}, betas,
    )


def _beta_for(beta: BetaLike, name: str, n_states: int) -> np.ndarray:
    value = beta.get(name) if isinstance(beta, Mapping) else beta
    if value is None:
        raise TPOError(f"no Lagrange multiplier given for objective '{name}'")
    b = np.broadcast_to(np.asarray(value, dtype=np.float64), (n_states,)) \
        if np.ndim(value) in (0, 1) and np.size(value) in (1, n_states) else None
    if b is None or not np.all(np.isfinite(b)) or np.any(b < 0):
        raise TPOError(f"multiplier for '{name}' must be finite, >= 0, a number or [S={n_states}]")
    return b
