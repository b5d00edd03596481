"""Layer 1: objectives, their DAG and slack (no numerics, no other tpo layer)."""

from tpo.graph.dag import Edge, ObjectiveGraph, local_slack, resolve_name

__all__ = ["Edge", "ObjectiveGraph", "local_slack", "resolve_name"]
