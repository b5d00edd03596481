"""The objective DAG of a topological MDP (paper §II-C, docs/design.md §1).

An :class:`ObjectiveGraph` holds ``k`` named objectives, the edges ``(w, v)``
("``w`` constrains ``v``") and one *local* slack ``eta_wv >= 0`` per edge. It is
built from edges, a chain or a spec string::

    ObjectiveGraph.parse("monitor>avoid>goal", slack=0)
    ObjectiveGraph.parse("A>G, M>G", slack=[0, 100], objectives=("goal", "avoid", "monitor"))

and validated on construction: every malformed input raises
:class:`~tpo.errors.GraphError` with a message naming the problem.
"""

from __future__ import annotations

import itertools
import math
import tomllib
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any, Literal, NamedTuple

import tomli_w

from tpo.errors import GraphError

SlackKind = Literal["local", "global"]
SlackLike = float | int | Sequence[float | int]


class Edge(NamedTuple):
    """An edge ``parent -> child`` with local slack ``eta`` (``child`` may lose at most
    ``eta`` of ``parent``'s optimal action value at every state)."""

    parent: str
    child: str
    slack: float


def local_slack(delta: float, gamma: float) -> float:
    """Local slack from global slack: ``eta = (1 - gamma) * delta`` (paper §II-C)."""
    _check_gamma(gamma)
    return (1.0 - gamma) * delta


def resolve_name(token: str, names: Sequence[str]) -> str:
    """The objective in ``names`` that ``token`` names.

    Matching is case-insensitive; an exact match wins, otherwise ``token`` must be
    the prefix of exactly one name (so ``"M"`` names ``"monitor"``).
    """
    key = token.strip().lower()
    if not key:
        raise GraphError("empty objective name")
    exact = [n for n in names if n.lower() == key]
    if exact:
        return exact[0]
    hits = [n for n in names if n.lower().startswith(key)]
    if len(hits) == 1:
        return hits[0]
    if not hits:
        raise GraphError(f"unknown objective {token.strip()!r}; known: {', '.join(names)}")
    raise GraphError(f"ambiguous objective {token.strip()!r}: matches {', '.join(hits)}")


@dataclass(frozen=True)
class ObjectiveGraph:
    """A validated DAG of named objectives with one local slack per edge.

    Attributes:
        objectives: names in declaration order (topological ties follow it).
        edges: the edges with their local slack, in declaration order.
    """

    objectives: tuple[str, ...]
    edges: tuple[Edge, ...] = field(default=())

    def __post_init__(self) -> None:
        object.__setattr__(self, "objectives", tuple(self.objectives))
        object.__setattr__(self, "edges", tuple(Edge(*e) for e in self.edges))
        _validate(self.objectives, self.edges)

    # ----------------------------------------------------------------- builders
    @classmethod
    def from_edges(
        cls,
        edges: Iterable[tuple[str, str]],
        slack: SlackLike = 0.0,
        *,
        objectives: Sequence[str] | None = None,
        slack_kind: SlackKind = "local",
        gamma: float | None = None,
    ) -> ObjectiveGraph:
        """A graph from ``(parent, child)`` pairs.

        Args:
            edges: the pairs, in declaration order.
            slack: one value for every edge, or one per edge in order.
            objectives: known names to resolve (case-insensitive unique prefix)
                edge names against; without it, edge names are used as written.
            slack_kind: ``"local"`` (``eta``) or ``"global"`` (``delta``, converted
                by ``eta = (1 - gamma) * delta``; needs ``gamma``).
            gamma: the discount, for global slack.
        """
        pairs = [tuple(e) for e in edges]
        for e in pairs:
            if len(e) != 2:
                raise GraphError(f"an edge is a (parent, child) pair, got {e!r}")
        names = [n for e in pairs for n in e]
        declared = _declare(names, objectives)
        resolved = [(declared[w], declared[v]) for w, v in pairs]
        etas = _slack_values(slack, len(resolved), slack_kind, gamma)
        nodes = list(dict.fromkeys(declared[n] for n in names))
        edges_ = (Edge(w, v, s) for (w, v), s in zip(resolved, etas, strict=True))
        return cls(tuple(nodes), tuple(edges_))

    @classmethod
    def chain(
        cls,
        names: Sequence[str],
        slack: SlackLike = 0.0,
        *,
        objectives: Sequence[str] | None = None,
        slack_kind: SlackKind = "local",
        gamma: float | None = None,
    ) -> ObjectiveGraph:
        """A chain ``names[0] > names[1] > ...`` (a lexicographic MDP)."""
        return cls.parse(">".join(names), slack, objectives=objectives,
                         slack_kind=slack_kind, gamma=gamma)

    @classmethod
    def parse(
        cls,
        spec: str,
        slack: SlackLike = 0.0,
        *,
        objectives: Sequence[str] | None = None,
        slack_kind: SlackKind = "local",
        gamma: float | None = None,
    ) -> ObjectiveGraph:
        """A graph from a spec string: comma-separated chains of ``>``-joined names.

        ``"monitor>avoid>goal"`` is a chain, ``"avoid>goal, monitor>goal"`` a fan;
        a lone name is a one-objective graph. See :meth:`from_edges` for the rest.
        """
        if not isinstance(spec, str):
            raise GraphError(f"a DAG spec is a string, got {type(spec).__name__}")
        if not spec.strip():
            raise GraphError("empty DAG spec")
        pairs: list[tuple[str, str]] = []
        lone: list[str] = []
        for chain in spec.split(","):
            tokens = [t.strip() for t in chain.split(">")]
            if any(not t for t in tokens):
                raise GraphError(f"empty objective name in DAG spec {spec.strip()!r}")
            pairs.extend(itertools.pairwise(tokens))
            if len(tokens) == 1:
                lone.append(tokens[0])
        if not pairs:
            declared = _declare(lone, objectives)
            nodes = tuple(dict.fromkeys(declared[n] for n in lone))
            _slack_values(slack, 0, slack_kind, gamma)
            return cls(nodes)
        graph = cls.from_edges(pairs, slack, objectives=objectives,
                               slack_kind=slack_kind, gamma=gamma)
        extra = [n for n in _declare(lone, objectives).values() if n not in graph.objectives]
        if extra:
            raise GraphError(f"objective(s) {', '.join(extra)} have no edge: several sinks")
        return graph

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], *,
                  objectives: Sequence[str] | None = None) -> ObjectiveGraph:
        """A graph from ``{"dag": spec, "slack": ..., "slack_kind": ..., "gamma": ...}``."""
        if not isinstance(data, Mapping):
            raise GraphError(f"a DAG table is a mapping, got {type(data).__name__}")
        unknown = set(data) - {"dag", "slack", "slack_kind", "gamma"}
        if unknown:
            raise GraphError(f"unknown DAG key(s): {', '.join(sorted(unknown))}")
        if "dag" not in data:
            raise GraphError("DAG table has no 'dag' key")
        kind = data.get("slack_kind", "local")
        if kind not in ("local", "global"):
            raise GraphError(f"slack_kind must be 'local' or 'global', got {kind!r}")
        return cls.parse(data["dag"], data.get("slack", 0.0), objectives=objectives,
                         slack_kind=kind, gamma=data.get("gamma"))

    @classmethod
    def from_toml(cls, text: str, *, objectives: Sequence[str] | None = None) -> ObjectiveGraph:
        """A graph from TOML text with the keys of :meth:`from_dict`."""
        try:
            data = tomllib.loads(text)
        except tomllib.TOMLDecodeError as err:
            raise GraphError(f"bad TOML: {err}") from None
        return cls.from_dict(data, objectives=objectives)

    def bind(self, names: Sequence[str]) -> ObjectiveGraph:
        """The same graph with every objective resolved against ``names`` (e.g. a
        model's reward columns), so ``"M>A>G"`` binds to monitor, avoid, goal."""
        declared = _declare(self.objectives, names)
        return ObjectiveGraph(
            tuple(declared[n] for n in self.objectives),
            tuple(Edge(declared[e.parent], declared[e.child], e.slack) for e in self.edges),
        )

    def with_slack(self, slack: SlackLike) -> ObjectiveGraph:
        """The same DAG with new local slack (one value, or one per edge)."""
        etas = _slack_values(slack, len(self.edges), "local", None)
        edges = (e._replace(slack=s) for e, s in zip(self.edges, etas, strict=True))
        return ObjectiveGraph(self.objectives, tuple(edges))

    # ------------------------------------------------------------ serialisation
    @property
    def spec(self) -> str:
        """The spec string, with consecutive edges merged into chains."""
        if not self.edges:
            return self.objectives[0]
        chains: list[list[str]] = []
        for e in self.edges:
            if chains and chains[-1][-1] == e.parent:
                chains[-1].append(e.child)
            else:
                chains.append([e.parent, e.child])
        return ", ".join(">".join(c) for c in chains)

    @property
    def slacks(self) -> tuple[float, ...]:
        """Local slack of every edge, in declaration order."""
        return tuple(e.slack for e in self.edges)

    def to_dict(self) -> dict[str, Any]:
        """``{"dag": spec, "slack": [...]}``, which :meth:`from_dict` reads back."""
        return {"dag": self.spec, "slack": list(self.slacks)}

    def to_toml(self) -> str:
        """TOML text that :meth:`from_toml` reads back."""
        return tomli_w.dumps(self.to_dict())

    def __str__(self) -> str:
        if not self.edges:
            return self.spec
        return f"{self.spec} (slack {', '.join(f'{s:g}' for s in self.slacks)})"

    # ---------------------------------------------------------------- structure
    @cached_property
    def order(self) -> tuple[str, ...]:
        """Topological order; ties broken by declaration order."""
        return _topological_order(self.objectives, self.edges)

    @property
    def leaf(self) -> str:
        """The unique sink, whose policy is the answer."""
        return self.order[-1]

    def parents(self, name: str) -> tuple[str, ...]:
        """Direct parents ``P_v`` of ``name``, in declaration order of the edges."""
        self._known(name)
        return tuple(e.parent for e in self.edges if e.child == name)

    def ancestors(self, name: str) -> tuple[str, ...]:
        """All ancestors ``A_i`` of ``name``, in topological order."""
        found: set[str] = set()
        stack = list(self.parents(name))
        while stack:
            w = stack.pop()
            if w not in found:
                found.add(w)
                stack.extend(self.parents(w))
        return tuple(n for n in self.order if n in found)

    def ancestral_edges(self, name: str) -> tuple[Edge, ...]:
        """``E_i``: the edges ``(w, v)`` with ``v`` in ``ancestors(i) ∪ {i}`` (paper §II-C)."""
        members = {*self.ancestors(name), name}
        return tuple(e for e in self.edges if e.child in members)

    def _known(self, name: str) -> None:
        if name not in self.objectives:
            raise GraphError(f"unknown objective {name!r}; known: {', '.join(self.objectives)}")


# -------------------------------------------------------------------- helpers
def _check_gamma(gamma: float | None) -> float:
    if gamma is None:
        raise GraphError("global slack needs gamma to convert (eta = (1 - gamma) * delta)")
    if isinstance(gamma, bool) or not isinstance(gamma, (int, float)) or not 0 <= gamma < 1:
        raise GraphError(f"gamma must be a number in [0, 1), got {gamma!r}")
    return float(gamma)


def _declare(names: Sequence[str], objectives: Sequence[str] | None) -> dict[str, str]:
    """Map every written name to its objective name."""
    for n in names:
        if not isinstance(n, str):
            raise GraphError(f"objective names are strings, got {n!r}")
        if not n.strip():
            raise GraphError("empty objective name")
    if objectives is None:
        return {n: n.strip() for n in names}
    return {n: resolve_name(n, objectives) for n in names}


def _slack_values(slack: SlackLike, n_edges: int, kind: SlackKind,
                  gamma: float | None) -> list[float]:
    if kind not in ("local", "global"):
        raise GraphError(f"slack kind must be 'local' or 'global', got {kind!r}")
    values = list(slack) if isinstance(slack, (list, tuple)) else [slack]
    for v in values:
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise GraphError(f"slack must be a number, got {v!r}")
        if math.isnan(v) or math.isinf(v):
            raise GraphError(f"slack must be finite, got {v}")
        if v < 0:
            raise GraphError(f"slack must be >= 0, got {v}")
    if len(values) == 1:
        values = values * n_edges
    elif len(values) != n_edges:
        raise GraphError(f"got {len(values)} slack values for {n_edges} edge(s); "
                         "give one value or one per edge")
    if kind == "global":
        g = _check_gamma(gamma)
        return [(1.0 - g) * float(v) for v in values]
    return [float(v) for v in values]


def _validate(objectives: tuple[str, ...], edges: tuple[Edge, ...]) -> None:
    if not objectives:
        raise GraphError("a DAG needs at least one objective")
    lowered = [n.lower() for n in objectives]
    for n in objectives:
        if not isinstance(n, str) or not n.strip() or any(c in n for c in ">,"):
            raise GraphError(f"bad objective name {n!r}: non-empty, without '>' or ','")
        if lowered.count(n.lower()) > 1:
            raise GraphError(f"duplicate objective {n!r}")
    seen: set[tuple[str, str]] = set()
    for e in edges:
        for n in (e.parent, e.child):
            if n not in objectives:
                raise GraphError(f"edge {e.parent}>{e.child} names unknown objective '{n}'")
        if e.parent == e.child:
            raise GraphError(f"self-loop on objective '{e.parent}'")
        if (e.parent, e.child) in seen:
            raise GraphError(f"duplicate edge {e.parent}>{e.child}")
        seen.add((e.parent, e.child))
        _slack_values(e.slack, 1, "local", None)
    _topological_order(objectives, edges)  # raises on a cycle
    sinks = [n for n in objectives if not any(e.parent == n for e in edges)]
    if len(sinks) != 1:
        raise GraphError(f"a DAG needs exactly one sink (leaf), found {len(sinks)}: "
                         f"{', '.join(sinks)}")


def _topological_order(objectives: tuple[str, ...], edges: tuple[Edge, ...]) -> tuple[str, ...]:
    indegree = {n: 0 for n in objectives}
    for e in edges:
        indegree[e.child] += 1
    order: list[str] = []
    while len(order) < len(objectives):
        ready = [n for n in objectives if indegree[n] == 0 and n not in order]
        if not ready:
            raise GraphError(f"cycle: {' > '.join(_find_cycle(objectives, edges))}")
        order.append(ready[0])
        for e in edges:
            if e.parent == ready[0]:
                indegree[e.child] -= 1
    return tuple(order)


def _find_cycle(objectives: tuple[str, ...], edges: tuple[Edge, ...]) -> list[str]:
    children = {n: [e.child for e in edges if e.parent == n] for n in objectives}
    state: dict[str, int] = {}
    path: list[str] = []

    def visit(n: str) -> list[str] | None:
        state[n] = 1
        path.append(n)
        for c in children[n]:
            if state.get(c) == 1:
                return [*path[path.index(c):], c]
            if c not in state and (cycle := visit(c)):
                return cycle
        path.pop()
        state[n] = 2
        return None

    for n in objectives:
        if n not in state and (cycle := visit(n)):
            return cycle
    raise AssertionError("no cycle found")  # unreachable: called only when Kahn stalls
