"""Shared Bellman machinery of the exact solvers.

Tolerances (DESIGN.md §2): value iteration stops when the value error is
provably below ``VI_TOL``; values are then polished by an exact evaluation of
the greedy policy, so in practice they are exact to ~1e-12. Ties and slack are
compared with ``ATOL``, far above that error, so tied actions are never lost
at zero slack and far below any slack a user would set.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from tpo.errors import TPOError
from tpo.graph import Edge
from tpo.tabular.evaluation import evaluate_policy
from tpo.tabular.model import TabularTMDP

VI_TOL = 1e-10
ATOL = 1e-7
MAX_ITERATIONS = 1_000_000


def masked_max(q: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Row-wise max of ``q`` over ``mask`` (``-inf`` where a row is empty)."""
    return np.where(mask, q, -np.inf).max(axis=1)


def restricted_value_iteration(model: TabularTMDP, reward: np.ndarray, allowed: np.ndarray,
                               tol: float = VI_TOL) -> tuple[np.ndarray, np.ndarray, int]:
    """Solve ``V(s) = max_{a in allowed(s)} r(s, a) + gamma E[V(s')]``.

    Value iteration, polished by exact policy evaluation: once the iterates
    settle, the greedy policy is evaluated exactly and accepted when its Bellman
    residual proves ``|V - V*| <= tol`` (residual / (1 - gamma)). Every
    non-terminal row of ``allowed`` must have an action.

    Returns ``(V [S], Q [S, A], iterations)``.
    """
    gamma = model.gamma
    live = ~model.terminal
    if not allowed[live].any(axis=1).all():
        raise AssertionError("every live state needs an allowed action")
    allowed = allowed | model.terminal[:, None]
    values = np.zeros(model.n_states)
    polish_at = 1e-4
    for iteration in range(1, MAX_ITERATIONS + 1):
        q = model.backup(reward, values)
        new = masked_max(q, allowed)
        change = np.max(np.abs(new - values))
        values = new
        if gamma == 0 or change * gamma <= tol * (1 - gamma):
            return values, model.backup(reward, values), iteration
        if change * gamma <= polish_at * (1 - gamma):
            policy = np.argmax(np.where(allowed, q, -np.inf), axis=1)
            exact = evaluate_policy(model, policy, reward)[:, 0]
            q = model.backup(reward, exact)
            residual = np.max(np.abs(masked_max(q, allowed) - exact))
            if residual <= tol * (1 - gamma):
                return exact, q, iteration
            values = exact  # V_pi <= V*, and value iteration from it rises monotonically
            polish_at /= 100
    raise TPOError(f"value iteration did not converge in {MAX_ITERATIONS} iterations")


def penalty(model: TabularTMDP, edges: Sequence[Edge], values: Mapping[str, np.ndarray],
            atol: float = ATOL) -> np.ndarray:
    """``sum_{(w,v) in edges} C_wv(s, a)`` with ``C_wv = max(0, -A_w(s, a) - eta_wv)``.

    ``-A_w(s, a) = V_w(s) - Q_w(s, a)``, where ``Q_w = R_w + gamma E[V_w]`` is the
    one-step value of ``w``'s reward under its values ``values[w]`` (paper Prop. 1).
    Violations at or below ``atol`` count as zero. Returns ``[S, A]``.
    """
    total = np.zeros((model.n_states, model.n_actions))
    for edge in edges:
        v_w = values[edge.parent]
        q_w = model.backup(model.rewards[:, :, model.index(edge.parent)], v_w)
        c = np.maximum(0.0, v_w[:, None] - q_w - edge.slack)
        total += np.where(c > atol, c, 0.0)
    return total


def greedy_with_ties(q: np.ndarray, allowed: np.ndarray, tie_breakers: Sequence[np.ndarray],
                     atol: float = ATOL) -> np.ndarray:
    """The best allowed action of every state, ties broken by ``tie_breakers``.

    Among the actions within ``atol`` of the best allowed ``q``, keep those within
    ``atol`` of the best of each tie-breaker in turn (the ancestors' Q-values,
    roots first), then take the lowest index (DESIGN.md §2).
    """
    keep = allowed & (q >= masked_max(q, allowed)[:, None] - atol)
    for qt in tie_breakers:
        keep &= qt >= masked_max(qt, keep)[:, None] - atol
    return np.argmax(keep, axis=1)
