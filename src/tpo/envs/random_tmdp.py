"""Random finite TMDPs with their exact models: a test bed for a learner that must
hold on problems nobody tuned it for, the way gymnax and Jumanji ship generators.

``random_tmdp(seed, ...)`` draws a :class:`RandomTMDP`: a :class:`TabularTMDP`
(every state reachable from the start), an :class:`ObjectiveGraph` over its
objectives with a slack on every edge, and an observation table. The same seed
and shape give the same problem on every machine (NumPy's ``default_rng``).
Serve it with :meth:`RandomTMDP.env` (a pure JAX env) or
:meth:`RandomTMDP.gym_env` (a Gymnasium env with a vector reward).

- **Moves**: deterministic (one successor per state and action) or stochastic
  (2 or 3 successors with Dirichlet probabilities); a random tree from the start
  makes every state reachable; a few states are terminal.
- **Rewards**: objective ``i`` has a scale ``c_i``, log-uniform over a spread of
  ``scale_spread`` (the first objective 1, the last ``scale_spread``, before the
  order is shuffled); dense rewards are uniform in ``[-c_i, c_i]`` on every state
  and action, sparse ones are 0 but on about 5 % of them, where they are in
  ``(0, c_i]``.
- **DAGs**: ``chain`` (a lexicographic MDP), ``fan`` (every other objective a root
  of the leaf: a constrained MDP) or ``dag`` (a random DAG with one leaf).
- **Slacks**: each edge's local slack is a share, drawn from ``slack``, of its
  parent's scale ``c_w``.
- **Observations**: ``onehot`` (a table) or ``embedding``: a random Gaussian
  feature vector of ``features`` numbers per state (function approximation).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from tpo.envs.tabular_env import TabularEnv, TabularGymEnv
from tpo.errors import TPOError
from tpo.graph import ObjectiveGraph
from tpo.tabular import TabularTMDP

DAGS = ("chain", "fan", "dag")
OBSERVATIONS = ("onehot", "embedding")
LIMITS = {"states": (10, 500), "actions": (2, 8), "objectives": (2, 6)}
TERMINAL_SHARE = 0.02  # of the states, at least one
SPARSE_SHARE = 0.05  # of the (state, action) pairs that pay a sparse reward


@dataclass(frozen=True, eq=False)
class RandomTMDP:
    """A generated problem.

    Attributes:
        model: the exact finite TMDP.
        graph: the objectives' DAG with its slacks.
        observations: ``[S, D]`` the observation of every state.
        scales: ``[k]`` each objective's reward scale ``c_i``.
        spec: the generator's arguments (:func:`random_tmdp` rebuilds it from them).
    """

    model: TabularTMDP
    graph: ObjectiveGraph
    observations: np.ndarray
    scales: np.ndarray
    spec: dict[str, Any]

    def env(self, random_start: bool = False, max_steps: int | None = None) -> TabularEnv:
        """The problem as a pure JAX env (exploring starts with ``random_start``)."""
        onehot = self.spec["observation"] == "onehot"
        return TabularEnv(self.model, None if onehot else self.observations,
                          max_steps or self.spec["max_steps"], random_start,
                          {"kind": "random_tmdp", **self.spec})

    def gym_env(self) -> TabularGymEnv:
        """The problem as a Gymnasium env with a vector reward (from the start)."""
        return TabularGymEnv(self.env(), self.graph)


def random_tmdp(seed: int, *, states: int = 50, actions: int = 4, objectives: int = 3,
                dag: str = "chain", stochastic: bool = False, sparse: bool = False,
                scale_spread: float = 100.0, slack: tuple[float, float] = (0.0, 1.0),
                observation: str = "onehot", features: int = 16, gamma: float = 0.99,
                max_steps: int = 200) -> RandomTMDP:
    """A random TMDP (module docstring); ``slack`` is the range of each edge's
    share of its parent's scale."""
    spec = {"seed": seed, "states": states, "actions": actions, "objectives": objectives,
            "dag": dag, "stochastic": stochastic, "sparse": sparse,
            "scale_spread": scale_spread, "slack": list(slack), "observation": observation,
            "features": features, "gamma": gamma, "max_steps": max_steps}
    _check(spec)
    rng = np.random.default_rng(seed)
    n, a, k = states, actions, objectives
    width = 3 if stochastic else 1
    terminal = np.zeros(n, bool)
    terminal[rng.choice(np.arange(1, n), max(1, int(TERMINAL_SHARE * n)), replace=False)] = True
    succ = rng.integers(0, n, size=(n, a, width))
    live = np.flatnonzero(~terminal)
    for s in range(1, n):  # a random tree from the start: every state is reachable
        parents = live[live < s]
        succ[parents[rng.integers(0, len(parents))], rng.integers(0, a), 0] = s
    probs = (rng.dirichlet(np.ones(width), size=(n, a)) if stochastic
             else np.ones((n, a, 1)))
    exponents = np.concatenate([[0.0], rng.uniform(0, 1, k - 2), [1.0]])[rng.permutation(k)]
    scales = scale_spread ** exponents
    if sparse:
        paid = rng.uniform(size=(n, a, k)) < SPARSE_SHARE
        rewards = np.where(paid, rng.uniform(0, 1, (n, a, k)), 0.0)
    else:
        rewards = rng.uniform(-1, 1, (n, a, k))
    rewards = rewards * scales
    rewards[terminal] = 0.0
    names = tuple(f"o{i}" for i in range(k))
    model = TabularTMDP(succ, probs, rewards, names, gamma, 0, terminal)
    edges = _edges(rng, dag, k)
    shares = rng.uniform(*slack, size=len(edges))
    slacks = [float(shares[e] * scales[w]) for e, (w, _) in enumerate(edges)]
    graph = ObjectiveGraph.from_edges([(names[w], names[v]) for w, v in edges], slacks,
                                      objectives=names)
    if observation == "onehot":
        table = np.eye(n, dtype=np.float32)
    else:
        table = (rng.standard_normal((n, features)) / np.sqrt(features)).astype(np.float32)
    return RandomTMDP(model, graph, table, scales, spec)


def random_gym_env(seed: int = 0, **kwargs: Any) -> TabularGymEnv:
    """``gym.make("tpo/RandomTMDP-v0", seed=..., ...)``: :func:`random_tmdp`'s problem
    as a Gymnasium env (its DAG: ``env.unwrapped.graph``)."""
    return random_tmdp(seed, **kwargs).gym_env()


def _edges(rng: np.random.Generator, dag: str, k: int) -> list[tuple[int, int]]:
    """The edges ``(parent, child)`` over objectives ``0 .. k - 1`` in a random
    topological order, the last of which is the leaf."""
    order = rng.permutation(k)
    if dag == "chain":
        return [(int(order[i]), int(order[i + 1])) for i in range(k - 1)]
    leaf = int(order[-1])
    if dag == "fan":
        return [(int(w), leaf) for w in order[:-1]]
    edges = []
    for i in range(k - 1):  # each node points to a later one, so the last is the one sink
        later = order[i + 1:]
        edges.append((int(order[i]), int(later[rng.integers(0, len(later))])))
        for j in later:  # and sometimes to more
            if (int(order[i]), int(j)) not in edges and rng.uniform() < 0.25:
                edges.append((int(order[i]), int(j)))
    return edges


def _check(spec: dict[str, Any]) -> None:
    """Raise :class:`TPOError` naming the first bad argument of :func:`random_tmdp`."""
    for name, (lo, hi) in LIMITS.items():
        value = spec[name]
        if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
            raise TPOError(f"{name} must be an integer from {lo} to {hi}, got {value!r:.40}")
    seed = spec["seed"]
    if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed < 2**63:
        raise TPOError(f"seed must be an integer from 0 to 2**63 - 1, got {seed!r:.40}")
    for name, choices in (("dag", DAGS), ("observation", OBSERVATIONS)):
        if spec[name] not in choices:
            raise TPOError(f"{name} must be one of {', '.join(choices)}, got "
                           f"{spec[name]!r:.40}")
    spread, slack = spec["scale_spread"], spec["slack"]
    if isinstance(spread, bool) or not isinstance(spread, int | float) \
            or not 1 <= spread <= 1e6:
        raise TPOError(f"scale_spread must be a number from 1 to 1e6, got {spread!r:.40}")
    if len(slack) != 2 or any(isinstance(v, bool) or not isinstance(v, int | float)
                              for v in slack) or not 0 <= slack[0] <= slack[1] <= 1:
        raise TPOError(f"slack must be a range (lo, hi) with 0 <= lo <= hi <= 1, got "
                       f"{slack!r:.40}")
    features = spec["features"]
    if isinstance(features, bool) or not isinstance(features, int) or not 1 <= features <= 1024:
        raise TPOError(f"features must be an integer from 1 to 1024, got {features!r:.40}")
    for name in ("stochastic", "sparse"):
        if not isinstance(spec[name], bool):
            raise TPOError(f"{name} must be true or false, got {spec[name]!r:.40}")
