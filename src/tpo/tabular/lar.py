"""LAR value iteration for any objective DAG (docs/design.md §2).

In topological order, objective ``v`` may use at state ``s`` the actions

    A_v(s) = { a in ∩_{w in P_v} A_w(s) : V_w(s) - Q_w(s, a) <= eta_wv for all w in P_v }

and solves ``V_v(s) = max_{a in A_v(s)} R_v(s, a) + gamma E[V_v(s')]``. By induction
``A_v(s)`` is exactly the set of actions with zero total violation
``sum_{(w,u) in E_v} C_wu(s, a)`` (paper Prop. 1), which is how it is computed.
The leaf's greedy policy, its ties settled by the lexicographic completion
(the ancestors' values over whole policies, roots first, then the lowest
index), is the answer.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from tpo.errors import InfeasibleError
from tpo.graph import ObjectiveGraph
from tpo.tabular.bellman import (
    ATOL,
    lexicographic_completion,
    masked_max,
    penalty,
    restricted_value_iteration,
)
from tpo.tabular.evaluation import evaluate_policy
from tpo.tabular.model import TabularTMDP


@dataclass(frozen=True, eq=False)
class Solution:
    """An exact solution: per-objective values and the leaf's greedy policy.

    Attributes:
        model, graph: the problem (graph bound to the model's objective names).
        values: ``V*_i [S]``, each objective's own (constrained) optimum.
        q_values: ``Q*_i [S, A]``.
        policy: ``[S]`` the leaf's greedy action at every state.
        policy_values: ``V_i^pi [S]`` of that policy for *every* model objective.
    """

    model: TabularTMDP
    graph: ObjectiveGraph
    values: dict[str, np.ndarray]
    q_values: dict[str, np.ndarray]
    policy: np.ndarray
    policy_values: dict[str, np.ndarray]

    @property
    def order(self) -> tuple[str, ...]:
        return self.graph.order

    def start_values(self) -> dict[str, float]:
        """``V*_i(s0)`` by objective, in topological order."""
        return {n: float(self.values[n][self.model.start]) for n in self.order}

    def start_policy_values(self) -> dict[str, float]:
        """``V_i^pi(s0)`` of the leaf's policy, by model objective."""
        return {n: float(v[self.model.start]) for n, v in self.policy_values.items()}


@dataclass(frozen=True, eq=False)
class LARSolution(Solution):
    """A LAR solution; adds the action sets and where they were relaxed.

    Attributes:
        allowed: ``A_i [S, A]`` bool, the actions objective ``i`` may use.
        relaxed: states where ``A_i`` was empty and was relaxed to the actions of
            least total violation (empty arrays for a feasible problem).
        iterations: value-iteration sweeps per objective.
    """

    allowed: dict[str, np.ndarray] = field(default_factory=dict)
    relaxed: dict[str, np.ndarray] = field(default_factory=dict)
    iterations: dict[str, int] = field(default_factory=dict)

    @property
    def feasible(self) -> bool:
        return not any(len(s) for s in self.relaxed.values())

    def summary(self) -> dict[str, Any]:
        """A JSON-ready summary at the start state."""
        return {
            "dag": self.graph.spec,
            "slack": list(self.graph.slacks),
            "gamma": self.model.gamma,
            "order": list(self.order),
            "values": self.start_values(),
            "policy_values": self.start_policy_values(),
            "feasible": self.feasible,
            "relaxed_states": {n: len(s) for n, s in self.relaxed.items() if len(s)},
        }


def solve_lar(model: TabularTMDP, graph: ObjectiveGraph, *, relax: bool = False,
              atol: float = ATOL) -> LARSolution:
    """Solve a TMDP exactly with local action restriction.

    Args:
        model: the finite model; its objective names are the reward columns.
        graph: the DAG (names resolved against the model's, so ``"M>A>G"`` works).
        relax: where an objective has no admissible action, keep the actions of
            least total violation (as the Lagrangian form with a very large
            multiplier would) instead of raising.
        atol: tolerance of "within slack" and of ties.

    Raises:
        InfeasibleError: some objective has an empty action set and ``relax`` is off.
    """
    graph = graph.bind(model.objectives)
    live = ~model.terminal
    values: dict[str, np.ndarray] = {}
    q_values: dict[str, np.ndarray] = {}
    allowed: dict[str, np.ndarray] = {}
    relaxed: dict[str, np.ndarray] = {}
    iterations: dict[str, int] = {}
    for name in graph.order:
        violation = penalty(model, graph.ancestral_edges(name), values, atol)
        ok = (violation == 0) | model.terminal[:, None]
        empty = live & ~ok.any(axis=1)
        if empty.any():
            if not relax:
                raise InfeasibleError(name, np.flatnonzero(empty).tolist())
            least = violation <= violation.min(axis=1, keepdims=True) + atol
            ok |= empty[:, None] & least
        reward = model.rewards[:, :, model.index(name)]
        values[name], q_values[name], iterations[name] = restricted_value_iteration(
            model, reward, ok)
        allowed[name], relaxed[name] = ok, np.flatnonzero(empty)
    policy = leaf_policy(model, graph, q_values[graph.leaf], allowed[graph.leaf], atol)
    exact = evaluate_policy(model, policy)
    return LARSolution(
        model, graph, values, q_values, policy,
        {n: exact[:, i] for i, n in enumerate(model.objectives)},
        allowed, relaxed, iterations,
    )


def leaf_policy(model: TabularTMDP, graph: ObjectiveGraph, q_leaf: np.ndarray,
                allowed: np.ndarray, atol: float = ATOL) -> np.ndarray:
    """The leaf's policy: its optimal actions among ``allowed``, ties settled by the
    lexicographic completion over the ancestors, roots first (docs/design.md §2)."""
    keep = (allowed & (q_leaf >= masked_max(q_leaf, allowed)[:, None] - atol)) \
        | model.terminal[:, None]
    ancestors = [model.rewards[:, :, model.index(n)] for n in graph.order[:-1]]
    return lexicographic_completion(model, keep, ancestors, atol)
