"""The phases of a TPO run and the constraints each keeps (docs/design.md §5), as
the static arrays the compiled program reads, and what a run's policy needs to
act (:class:`Acting`)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

import jax
import numpy as np

from tpo.algo.config import ConfigError, TPOConfig
from tpo.algo.networks import ValueNorm
from tpo.graph import ObjectiveGraph


@dataclass(frozen=True)
class Problem:
    """The static structure of a run that the compiled program needs: its phases
    and the constraints each phase keeps (docs/design.md §5).

    Phase ``p`` trains critic head ``p`` on reward column ``reward[p]``: first the
    graph's objectives in topological order (Algorithm 1); then, with
    ``completion``, one *completion* phase per ancestor of the leaf, roots
    first, which keeps the leaf's and the earlier completion phases' values at
    zero slack (the tie rule of docs/design.md §2, learned). Without it, a run
    that ends by choosing among its phases' policies (``select``) on a graph of
    several roots learns the *roots' completion* after the leaf
    (``roots_completion``): one phase for
    every root after the first that keeps the earlier roots at zero slack
    (``M`` under ``A`` in the fan ``A>G, M>G``), a policy that no objective's own
    phase learns, and the tie rule's answer where the leaf is indifferent
    (docs/notes/tpo-learning.md, session 30).

    Attributes:
        objectives: the env's objective names (reward columns).
        graph: the DAG, bound to ``objectives``.
        reward: ``[P]`` reward column of every phase.
        head: ``[C]`` the critic head (a phase) whose values constraint ``c`` reads.
        slack_index: ``[C]`` its slack: an edge's index, or ``n_edges`` for zero.
        active: ``[P, C]`` 1 where phase ``p`` keeps constraint ``c``.
        start: ``[P]`` the phase whose final policy phase ``p`` starts from: the one
            before it, but a roots' completion phase starts from its root's own
            policy (which knows where that objective's reward lies).
        reference: the phase whose policy is the run's own: the leaf's, or the last
            completion phase's (the roots' completion phases only offer candidates).
        phase_names: the objective of every phase, the extra phases marked.
    """

    objectives: tuple[str, ...]
    graph: ObjectiveGraph
    reward: np.ndarray
    head: np.ndarray
    slack_index: np.ndarray
    active: np.ndarray
    start: np.ndarray
    reference: int
    phase_names: tuple[str, ...]

    @classmethod
    def build(cls, graph: ObjectiveGraph, objectives: Sequence[str], config: TPOConfig
              ) -> Problem:
        graph = graph.bind(tuple(objectives))
        col = {n: i for i, n in enumerate(objectives)}
        phase = {n: i for i, n in enumerate(graph.order)}
        n_edges = len(graph.edges)
        constraints = [(phase[e.parent], j) for j, e in enumerate(graph.edges)]
        rows = [[j for j, e in enumerate(graph.edges) if e in graph.ancestral_edges(n)]
                for n in graph.order]
        reward = [col[n] for n in graph.order]
        names = list(graph.order)
        start = list(range(-1, len(reward) - 1))
        roots = [n for n in graph.order if not graph.parents(n)]
        if config.completion and n_edges:
            kept = [*rows[-1], len(constraints)]
            constraints.append((phase[graph.leaf], n_edges))  # the leaf, at zero slack
            for i, name in enumerate(graph.order[:-1]):
                if i:  # the previous completion phase, at zero slack
                    kept = [*kept, len(constraints)]
                    constraints.append((len(reward) - 1, n_edges))
                rows.append(kept)
                start.append(len(reward) - 1)
                reward.append(col[name])
                names.append(f"{name} (completion)")
        reference = len(reward) - 1
        if config.select and config.roots_completion and not config.completion \
                and len(roots) > 1:
            kept, held = [], phase[roots[0]]  # the phase holding the roots before
            for name in roots[1:]:
                kept = [*kept, len(constraints)]
                constraints.append((held, n_edges))
                rows.append(kept)
                start.append(phase[name])
                reward.append(col[name])
                names.append(f"{name} (under {'+'.join(roots[:len(kept)])})")
                held = len(reward) - 1
        active = np.zeros((len(rows), len(constraints)), np.float32)
        for p, row in enumerate(rows):
            active[p, row] = 1.0
        pairs = np.array(constraints, np.int32).reshape(-1, 2)
        return cls(tuple(objectives), graph, np.array(reward, np.int32), pairs[:, 0],
                   pairs[:, 1], active, np.array(start, np.int32), reference, tuple(names))

    @property
    def n_phases(self) -> int:
        return len(self.reward)


MAX_UPDATES = 2**31 - 1  # the update counter is an int32


def phase_updates(config: TPOConfig, n_phases: int, total_timesteps: int) -> np.ndarray:
    """The updates ``[P]`` of every phase of a run of ``total_timesteps`` steps: their
    shares of the budget (``config.phase_fractions``, by default equal), at least one
    each."""
    if config.phase_fractions is not None and len(config.phase_fractions) != n_phases:
        raise ConfigError(f"phase_fractions has {len(config.phase_fractions)} values for "
                          f"{n_phases} phase(s)")
    fractions = np.asarray(config.phase_fractions or [1.0] * n_phases, float)
    fractions = fractions / fractions.max()  # sums without overflow
    per_update = config.batch_size
    most = per_update * (MAX_UPDATES - 1)
    if isinstance(total_timesteps, bool) or not isinstance(total_timesteps, int) \
            or not per_update * n_phases <= total_timesteps <= most:
        raise ConfigError(f"total_timesteps must be an integer from {per_update * n_phases} "
                          f"(one update of {per_update} steps per phase) to {most:.3g} "
                          f"(the update counter is int32), got {total_timesteps!r}")
    return np.maximum(1, np.floor(total_timesteps / per_update * fractions
                                  / fractions.sum())).astype(np.int32)


class Acting(NamedTuple):
    """What a run's policy needs to act (:meth:`Trainer.policy`): the actor, and in
    the restriction form the frozen critics, their value statistics, the slack
    and the phase whose constraints hold."""

    actor: dict
    critics: dict
    value_norm: ValueNorm
    slack: jax.Array  # [n_edges]
    phase: jax.Array  # int32 []


def reward_ranges(reward_low: np.ndarray, reward_high: np.ndarray) -> np.ndarray:
    """The largest one-step reward difference of every objective,
    ``max(|r_lo|, |r_hi|, r_hi - r_lo)`` (1 where a bound is unknown)."""
    return _known(_range(reward_low, reward_high))


def value_bounds(reward_low: np.ndarray, reward_high: np.ndarray, gamma: float) -> np.ndarray:
    """The largest value difference of every objective, ``reward_ranges / (1 - gamma)``
    (1 where a bound is unknown)."""
    return _known(_range(reward_low, reward_high) / (1 - gamma))


def _range(reward_low: np.ndarray, reward_high: np.ndarray) -> np.ndarray:
    lo, hi = np.asarray(reward_low, float), np.asarray(reward_high, float)
    return np.maximum.reduce([np.abs(lo), np.abs(hi), hi - lo])


def _known(bound: np.ndarray) -> np.ndarray:
    return np.where(np.isfinite(bound) & (bound > 0), bound, 1.0)
