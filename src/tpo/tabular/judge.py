"""Judging a policy by the TMDP's own criterion, exactly (docs/design.md §6).

Against a LAR solution (relaxed where the problem is infeasible), a policy is

- **LAR-correct**: the leaf's value at the start is within ``tol`` of ``V*_leaf``,
  and every ancestor ``w`` keeps at least ``floor_w(s0) - tol``, where ``floor_w``
  is the least value of ``w`` over all policies that take only the leaf's
  admissible actions ``A_leaf(s)`` (what LAR guarantees ``w``);
- **strict**: LAR-correct, and every action it takes in the states it reaches
  from the start lies in ``A_leaf(s)``;
- **same values**: every objective of the DAG within ``tol`` of the value of the
  solver's own policy (the lexicographic completion).

The tolerance of objective ``k`` around a reference value ``v`` is
``tol_k(v) = max(0.02 |v|, a_k)``. Its absolute part ``a_k`` is 0.5 on the
navigation maps (rewards of -1/0/+1 a step); on any other problem it is
``0.0025 R_k``, ``R_k`` the objective's value range at the start (its best
minus its worst value over all policies; 0.5 where ``R_k`` is 200), so that
multiplying an objective's rewards by a constant changes no verdict
(docs/design.md §6).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tpo.tabular.bellman import restricted_value_iteration
from tpo.tabular.evaluation import evaluate_policy
from tpo.tabular.lar import LARSolution
from tpo.tabular.model import TabularTMDP

REL_TOL, ABS_TOL = 0.02, 0.5
RANGE_SHARE = 0.0025  # of an objective's value range: the scale-free absolute part
FLOAT_TOL = 1e-9  # the least absolute part: float error, where an objective is constant
VERDICTS = ("lar_correct", "strict", "same_values")  # the verdicts of a Verdict


def tolerance(reference: np.ndarray | float, rel: float = REL_TOL,
              absolute: float = ABS_TOL) -> np.ndarray:
    """``max(rel |v|, absolute)`` of a reference value ``v`` (by default 2 %, or 0.5)."""
    return np.maximum(rel * np.abs(reference), absolute)


def value_ranges(model: TabularTMDP) -> dict[str, float]:
    """``R_k``: every objective's best minus its worst value at the start, over all
    policies (two value iterations each)."""
    every = np.ones((model.n_states, model.n_actions), bool)
    out = {}
    for k, name in enumerate(model.objectives):
        r = model.rewards[:, :, k]
        best = restricted_value_iteration(model, r, every)[0][model.start]
        worst = -restricted_value_iteration(model, -r, every)[0][model.start]
        out[name] = float(best - worst)
    return out


def floors(solution: LARSolution) -> dict[str, np.ndarray]:
    """``floor_w [S]`` of every ancestor ``w`` of the leaf: the least value of ``w``
    over the policies restricted to ``A_leaf`` (a min-value iteration)."""
    model, graph = solution.model, solution.graph
    allowed = solution.allowed[graph.leaf]
    return {w: -restricted_value_iteration(
        model, -model.rewards[:, :, model.index(w)], allowed)[0] for w in graph.order[:-1]}


def reachable(model: TabularTMDP, policy: np.ndarray) -> np.ndarray:
    """``[S]`` bool: the states a deterministic ``policy`` reaches from the start
    with positive probability (terminal states included)."""
    seen = np.zeros(model.n_states, bool)
    frontier = [model.start]
    seen[model.start] = True
    while frontier:
        s = frontier.pop()
        if model.terminal[s]:
            continue
        a = policy[s]
        for nxt in model.successors[s, a][model.probs[s, a] > 0]:
            if not seen[nxt]:
                seen[nxt] = True
                frontier.append(int(nxt))
    return seen


@dataclass(frozen=True)
class Verdict:
    """A policy judged against a LAR solution; values at the start state.

    Attributes:
        lar_correct, strict, same_values: the three verdicts (module docstring).
        feasible: whether the problem was feasible (else judged against the
            relaxed solution).
        values: the policy's value of every model objective.
        optimum: ``V*_leaf(s0)``.
        floors: ``floor_w(s0)`` of every ancestor.
        reference: the solver's policy's value of every model objective.
        outside: states on the policy's way from the start where it leaves ``A_leaf``.
    """

    lar_correct: bool
    strict: bool
    same_values: bool
    feasible: bool
    values: dict[str, float]
    optimum: float
    floors: dict[str, float]
    reference: dict[str, float]
    outside: tuple[int, ...]

class Judge:
    """Judges policies against one solution (its references computed once).

    ``absolute``: the tolerance's absolute part for every objective in reward units
    (:data:`ABS_TOL` on the navigation maps); by default each objective's own
    ``RANGE_SHARE * R_k`` (:func:`value_ranges`), which no reward unit changes."""

    def __init__(self, solution: LARSolution, absolute: float | None = None) -> None:
        self.solution = solution
        model = solution.model
        self.absolute = ({n: float(absolute) for n in model.objectives} if absolute is not None
                         else {n: max(RANGE_SHARE * r, FLOAT_TOL)
                               for n, r in value_ranges(model).items()})
        start = solution.model.start
        self.floors = {w: float(f[start]) for w, f in floors(solution).items()}
        self.optimum = float(solution.values[solution.graph.leaf][start])
        self.reference = solution.start_policy_values()

    def __call__(self, policy: np.ndarray) -> Verdict:
        """The verdict of a deterministic ``policy [S]`` (greedy actions)."""
        sol = self.solution
        model, graph, start = sol.model, sol.graph, sol.model.start
        policy = np.asarray(policy)
        values = dict(zip(model.objectives, map(float, evaluate_policy(model, policy)[start]),
                          strict=True))
        correct = self.lar_correct(values)
        on_way = reachable(model, policy) & ~model.terminal
        inside = sol.allowed[graph.leaf][np.arange(model.n_states), policy]
        outside = tuple(int(s) for s in np.flatnonzero(on_way & ~inside))
        return Verdict(bool(correct), bool(correct and not outside),
                       self.same_values(values), sol.feasible,
                       values, self.optimum, self.floors, self.reference, outside)

    def tolerance(self, name: str, reference: float, rel: float = REL_TOL) -> float:
        """``tol_k`` of objective ``name`` around a ``reference`` value."""
        return float(tolerance(reference, rel, self.absolute[name]))

    def same_values(self, values: dict[str, float], rel: float = REL_TOL) -> bool:
        """Every objective of the DAG within its :meth:`tolerance` of LAR's policy's
        value at the start (by value alone, as :meth:`lar_correct`)."""
        return all(abs(values[n] - self.reference[n]) <= self.tolerance(n, self.reference[n], rel)
                   for n in self.solution.graph.objectives)

    def lar_correct(self, values: dict[str, float], rel: float = REL_TOL) -> bool:
        """LAR-correct by value alone: the leaf's start value ``values`` within its
        :meth:`tolerance` of ``V*_leaf(s0)`` or above it, every ancestor's at least
        its floor less its tolerance (for values estimated elsewhere, e.g. by Monte
        Carlo on the continuous env that this solution approximates)."""
        leaf = self.solution.graph.leaf
        return bool(values[leaf] >= self.optimum - self.tolerance(leaf, self.optimum, rel)
                    and all(values[w] >= f - self.tolerance(w, f, rel)
                            for w, f in self.floors.items()))
