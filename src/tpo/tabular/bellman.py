"""Shared Bellman machinery of the exact solvers.

Tolerances (docs/design.md §2): value iteration stops when the value error is
provably below ``VI_TOL``; values are then polished by an exact evaluation of
the greedy policy, so in practice they are exact to ~1e-12. Ties and slack are
compared with ``ATOL``, far above that error, so tied actions are never lost
at zero slack and far below any slack a user would set.
"""

from __future__ import annotations

import itertools
import os
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from tpo.errors import TPOError
from tpo.graph import Edge
from tpo.tabular.evaluation import evaluate_policy
from tpo.tabular.model import TabularTMDP

VI_TOL = 1e-10
ATOL = 1e-7
MAX_ITERATIONS = 1_000_000
PARALLEL_STATES = 200_000


def masked_max(q: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Row-wise max of ``q`` over ``mask`` (``-inf`` where a row is empty)."""
    return np.where(mask, q, -np.inf).max(axis=1)


def restricted_value_iteration(model: TabularTMDP, reward: np.ndarray, allowed: np.ndarray,
                               tol: float = VI_TOL) -> tuple[np.ndarray, np.ndarray, int]:
    """Solve ``V(s) = max_{a in allowed(s)} r(s, a) + gamma E[V(s')]``.

    Value iteration, polished by exact policy evaluation: every so often the
    greedy policy is evaluated exactly and accepted when its Bellman residual
    proves ``|V - V*| <= tol`` (residual / (1 - gamma)). That ends the slow
    geometric tail of value iteration as soon as the policy is right. Polishing
    is scheduled geometrically and kept to about a quarter of the sweeping
    time. Every non-terminal row of ``allowed`` must have an action.

    Returns ``(V [S], Q [S, A], iterations)``.
    """
    gamma = model.gamma
    allowed = allowed | model.terminal[:, None]
    if not allowed.any(axis=1).all():
        raise AssertionError("every live state needs an allowed action")
    base = np.ascontiguousarray(np.where(allowed, reward, -np.inf).T)  # [A, S]
    succ, probs = model.action_major

    def sweep_block(values: np.ndarray, out: np.ndarray, block: slice) -> float:
        best = out[block]
        for a in range(model.n_actions):
            if model.deterministic:
                q = values[succ[a, block, 0]]
            else:
                q = np.einsum("sb,sb->s", probs[a, block], values[succ[a, block]])
            q *= gamma
            q += base[a, block]
            if a == 0:
                best[:] = q
            else:
                np.maximum(best, q, out=best)
        return float(np.max(np.abs(best - values[block]), initial=0.0))

    blocks = _blocks(model.n_states)
    with ThreadPoolExecutor(len(blocks)) as pool:

        def sweep(values: np.ndarray, out: np.ndarray) -> float:
            """One Bellman sweep of ``values`` into ``out``; returns the max change."""
            if len(blocks) == 1:
                return sweep_block(values, out, blocks[0])
            return max(pool.map(lambda b: sweep_block(values, out, b), blocks))

        return _iterate(model, reward, allowed, sweep, tol)


def _blocks(n_states: int) -> list[slice]:
    """State blocks swept in parallel: NumPy's gathers release the GIL, so large
    models use every core (measured 1.7x on 2 cores at 1 M states)."""
    n = min(os.cpu_count() or 1, 8) if n_states >= PARALLEL_STATES else 1
    edges = np.linspace(0, n_states, n + 1).astype(int)
    return [slice(lo, hi) for lo, hi in itertools.pairwise(edges)]


def _iterate(model: TabularTMDP, reward: np.ndarray, allowed: np.ndarray,
             sweep: Callable[[np.ndarray, np.ndarray], float],
             tol: float) -> tuple[np.ndarray, np.ndarray, int]:
    gamma = model.gamma
    values, spare = np.zeros(model.n_states), np.empty(model.n_states)
    next_polish, polishes = 8, 0
    cost = _polish_cost(model)
    for iteration in range(1, MAX_ITERATIONS + 1):
        change = sweep(values, spare)
        values, spare = spare, values
        if change * gamma <= _bound(tol, gamma, values):
            return values, model.backup(reward, values), iteration
        if iteration >= next_polish:
            polishes += 1
            q = np.where(allowed, model.backup(reward, values), -np.inf)
            exact = evaluate_policy(model, np.argmax(q, axis=1), reward)[:, 0]
            if sweep(exact, spare) <= _bound(tol, gamma, exact):
                return exact, model.backup(reward, exact), iteration
            values = exact  # V_pi <= V*, and value iteration from it rises monotonically
            # Keep polishing to about a quarter of the work spent sweeping (a
            # schedule of counts, not of clock time, so results are reproducible).
            next_polish = iteration + max(8, iteration // 4, int(4 * polishes * cost))
    raise TPOError(f"value iteration did not converge in {MAX_ITERATIONS} iterations")


def _bound(tol: float, gamma: float, values: np.ndarray) -> float:
    """The Bellman residual that proves ``|V - V*| <= tol``, but no less than the
    rounding of a sweep (16 ulps of the largest value): at values of 1e4 (rewards of
    100) a residual of ``tol (1 - gamma)`` = 1e-12 is below float64's reach."""
    return max(tol * (1 - gamma), 16 * np.finfo(np.float64).eps * float(
        np.max(np.abs(values), initial=0.0)))


def _polish_cost(model: TabularTMDP) -> float:
    """The work of one exact evaluation in sweeps: pointer jumping does about half
    a sweep per doubling up to the horizon where gamma^H < 1e-17; a sparse LU is
    taken as 20 sweeps."""
    if not model.deterministic or model.gamma == 0:
        return 20.0
    horizon = np.log(1e-17) / np.log(model.gamma)
    return 0.5 * float(np.ceil(np.log2(max(horizon, 2.0))))


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


def lexicographic_completion(model: TabularTMDP, keep: np.ndarray,
                             rewards: Sequence[np.ndarray], atol: float = ATOL) -> np.ndarray:
    """The leaf's policy by the tie rule of docs/design.md §2.

    ``keep [S, A]`` holds the leaf's optimal admissible actions. The freedom left
    goes to the ``rewards [S, A]`` in turn (the ancestors', roots first), each at
    zero slack: optimise its value over the policies restricted to ``keep``, keep
    the actions within ``atol`` of its best, go on with the next; then take the
    lowest index. This is LAR on the chain ``leaf -> root -> ...`` at slack 0, so
    it optimises whole policies, not one state's Q at a time.
    """
    for reward in rewards:
        _, q, _ = restricted_value_iteration(model, reward, keep)
        keep = keep & (q >= masked_max(q, keep)[:, None] - atol)
    return np.argmax(keep, axis=1)
