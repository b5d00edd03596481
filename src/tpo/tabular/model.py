"""A finite multi-objective MDP in a compact, sparse form (docs/design.md §2).

Transitions are stored as padded successor lists, not as a dense ``S x A x S``
array: ``successors[s, a, b]`` is the ``b``-th possible next state of ``(s, a)``
and ``probs[s, a, b]`` its probability (duplicates allowed, padding has
probability 0). A deterministic 1 M-state grid with 4 actions takes 4 M
indices; a dense array would take 4·10^12 numbers.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from functools import cached_property

import numpy as np
import scipy.sparse as sp

from tpo.errors import ModelError

PROB_ATOL = 1e-9


@dataclass(frozen=True, eq=False)
class TabularTMDP:
    """A finite MDP with ``k`` named reward objectives.

    Attributes:
        successors: int ``[S, A, B]`` next-state indices.
        probs: float ``[S, A, B]`` their probabilities (each ``(s, a)`` sums to 1).
        rewards: float ``[S, A, k]``, ``R_i(s, a)``.
        objectives: the ``k`` objective names, one per reward column.
        gamma: discount in ``[0, 1)``.
        start: the start state ``s0``.
        terminal: bool ``[S]``; terminal states are absorbing with zero reward
            (their transition rows are replaced by self-loops; their rewards must be 0).
    """

    successors: np.ndarray
    probs: np.ndarray
    rewards: np.ndarray
    objectives: tuple[str, ...]
    gamma: float
    start: int = 0
    terminal: np.ndarray | None = None

    def __post_init__(self) -> None:
        succ = np.asarray(self.successors)
        probs = np.asarray(self.probs, dtype=np.float64)
        rewards = np.asarray(self.rewards, dtype=np.float64)
        if succ.ndim != 3:
            raise ModelError(f"successors must be [S, A, B], got shape {succ.shape}")
        if probs.shape != succ.shape:
            raise ModelError(f"probs shape {probs.shape} != successors shape {succ.shape}")
        n_states, n_actions, _ = succ.shape
        if n_states == 0 or n_actions == 0 or succ.shape[2] == 0:
            raise ModelError(f"empty model: successors shape {succ.shape}")
        if rewards.ndim != 3 or rewards.shape[:2] != (n_states, n_actions):
            raise ModelError(f"rewards must be [S={n_states}, A={n_actions}, k], "
                             f"got shape {rewards.shape}")
        objectives = tuple(self.objectives)
        if rewards.shape[2] != len(objectives):
            raise ModelError(f"rewards have {rewards.shape[2]} column(s) but "
                             f"{len(objectives)} objective name(s) {objectives}")
        if len(set(objectives)) != len(objectives) or not all(
                isinstance(n, str) and n for n in objectives):
            raise ModelError(f"objective names must be unique non-empty strings: {objectives}")
        if not np.issubdtype(succ.dtype, np.integer):
            raise ModelError(f"successors must be integers, got dtype {succ.dtype}")
        if succ.size and (succ.min() < 0 or succ.max() >= n_states):
            raise ModelError(f"successor index out of range [0, {n_states})")
        terminal = (np.zeros(n_states, bool) if self.terminal is None
                    else np.asarray(self.terminal))
        if terminal.shape != (n_states,) or terminal.dtype != bool:
            raise ModelError(f"terminal must be a bool array of shape ({n_states},), "
                             f"got {terminal.dtype} {terminal.shape}")
        live = ~terminal
        if not np.all(np.isfinite(probs[live])) or np.any(probs[live] < 0):
            raise ModelError("transition probabilities must be finite and >= 0")
        sums = probs[live].sum(axis=-1)
        if sums.size and np.max(np.abs(sums - 1.0)) > PROB_ATOL:
            s, a = np.argwhere(np.abs(probs.sum(-1) - 1.0) * live[:, None] > PROB_ATOL)[0]
            raise ModelError(f"transition probabilities of state {s}, action {a} sum to "
                             f"{probs[s, a].sum():.12g}, not 1")
        if not np.all(np.isfinite(rewards)):
            s, a, i = np.argwhere(~np.isfinite(rewards))[0]
            raise ModelError(f"non-finite reward at state {s}, action {a}, "
                             f"objective '{objectives[i]}'")
        bad = terminal & (rewards != 0).any(axis=(1, 2))
        if bad.any():
            raise ModelError("terminal states are absorbing with zero reward; "
                             f"state {int(np.flatnonzero(bad)[0])} has a non-zero reward")
        gamma = self.gamma
        if isinstance(gamma, bool) or not isinstance(gamma, (int, float, np.floating)) \
                or not 0 <= gamma < 1:
            raise ModelError(f"gamma must be a number in [0, 1), got {gamma!r}")
        start = self.start
        if isinstance(start, bool) or not isinstance(start, (int, np.integer)) \
                or not 0 <= start < n_states:
            raise ModelError(f"start state must be an index in [0, {n_states}), got {start!r}")
        index_type = np.int32 if n_states < 2**31 else np.int64
        succ = np.array(succ, dtype=index_type)
        probs = np.array(probs)
        succ[terminal] = np.flatnonzero(terminal)[:, None, None]
        probs[terminal] = 0.0
        probs[terminal, :, 0] = 1.0
        object.__setattr__(self, "successors", succ)
        object.__setattr__(self, "probs", probs)
        object.__setattr__(self, "rewards", np.ascontiguousarray(rewards))
        object.__setattr__(self, "objectives", objectives)
        object.__setattr__(self, "gamma", float(gamma))
        object.__setattr__(self, "start", int(start))
        object.__setattr__(self, "terminal", terminal)

    @classmethod
    def from_dense(cls, transitions: np.ndarray, rewards: np.ndarray,
                   objectives: Sequence[str], gamma: float, start: int = 0,
                   terminal: np.ndarray | None = None) -> TabularTMDP:
        """A model from a dense ``T[s, a, s']`` array (for small, hand-made models)."""
        t = np.asarray(transitions, dtype=np.float64)
        if t.ndim != 3 or t.shape[0] != t.shape[2]:
            raise ModelError(f"dense transitions must be [S, A, S], got shape {t.shape}")
        width = max(1, int((t > 0).sum(-1).max()))
        order = np.argsort(t <= 0, axis=-1, kind="stable")[..., :width]
        return cls(order, np.take_along_axis(t, order, axis=-1), rewards,
                   tuple(objectives), gamma, start, terminal)

    # ---------------------------------------------------------------- accessors
    @property
    def n_states(self) -> int:
        return self.successors.shape[0]

    @property
    def n_actions(self) -> int:
        return self.successors.shape[1]

    def index(self, name: str) -> int:
        """Reward column of objective ``name``."""
        try:
            return self.objectives.index(name)
        except ValueError:
            raise ModelError(f"unknown objective '{name}'; the model has "
                             f"{', '.join(self.objectives)}") from None

    def with_gamma(self, gamma: float) -> TabularTMDP:
        """The same model with another discount."""
        return replace(self, gamma=gamma)

    def rescaled(self, objective: str, c: float) -> TabularTMDP:
        """The same model with ``objective``'s rewards multiplied by ``c``."""
        rewards = self.rewards.copy()
        rewards[..., self.index(objective)] *= c
        return replace(self, rewards=rewards)

    @cached_property
    def deterministic(self) -> bool:
        """Whether every ``(s, a)`` has a single successor."""
        return self.successors.shape[2] == 1

    @cached_property
    def action_major(self) -> tuple[np.ndarray, np.ndarray]:
        """``successors`` and ``probs`` as contiguous ``[A, S, B]`` arrays: per-action
        gathers over all states are what value iteration spends its time on."""
        return (np.ascontiguousarray(self.successors.transpose(1, 0, 2)),
                np.ascontiguousarray(self.probs.transpose(1, 0, 2)))

    # ------------------------------------------------------------------ algebra
    def expect(self, values: np.ndarray) -> np.ndarray:
        """``E[V(s') | s, a]`` for ``values`` ``[S]`` or ``[S, m]``; shape ``[S, A(, m)]``."""
        if self.deterministic:
            return values[self.successors[:, :, 0]]
        nxt = values[self.successors]
        if values.ndim == 1:
            return np.einsum("sab,sab->sa", self.probs, nxt)
        return np.einsum("sab,sabm->sam", self.probs, nxt)

    def backup(self, reward: np.ndarray, values: np.ndarray) -> np.ndarray:
        """``Q(s, a) = r(s, a) + gamma * E[V(s')]`` (zero at terminal states when
        ``reward`` is zero there and ``values`` is a solution)."""
        return reward + self.gamma * self.expect(values)

    def policy_matrix(self, policy: np.ndarray) -> sp.csr_matrix:
        """``P_pi[s, s']`` of a deterministic ``[S]`` or stochastic ``[S, A]`` policy."""
        probs = policy_probs(policy, self.n_states, self.n_actions)
        weights = probs[:, :, None] * self.probs
        rows = np.broadcast_to(np.arange(self.n_states)[:, None, None], weights.shape)
        keep = weights > 0
        return sp.csr_matrix((weights[keep], (rows[keep], self.successors[keep])),
                             shape=(self.n_states, self.n_states))


def policy_probs(policy: np.ndarray, n_states: int, n_actions: int) -> np.ndarray:
    """``pi[s, a]`` from a deterministic policy ``[S]`` (action indices) or ``[S, A]``."""
    policy = np.asarray(policy)
    if policy.ndim == 0 or policy.shape[0] != n_states:
        raise ModelError(f"a policy needs one row per state ({n_states}), got shape {policy.shape}")
    if policy.ndim == 1:
        if not np.issubdtype(policy.dtype, np.integer) or policy.min(initial=0) < 0 \
                or policy.max(initial=0) >= n_actions:
            raise ModelError(f"a deterministic policy holds action indices in [0, {n_actions})")
        return np.eye(n_actions)[policy]
    if policy.ndim != 2 or policy.shape[1] != n_actions:
        raise ModelError(f"a stochastic policy is [S, A={n_actions}], got shape {policy.shape}")
    if not np.all(np.isfinite(policy)) or np.any(policy < 0) \
            or np.max(np.abs(policy.sum(1) - 1.0)) > PROB_ATOL:
        raise ModelError("a stochastic policy's rows must be probabilities summing to 1")
    return policy.astype(np.float64)
