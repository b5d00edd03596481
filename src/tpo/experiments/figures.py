"""The reproduction's Figure 2: per panel, the DAG and each objective's value against
slack (learned: solid, seed spread shaded; LAR: dashed, infeasible points marked)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure

from tpo.graph import ObjectiveGraph

COLORS = {"avoid": "red", "monitor": "blue", "goal": "green"}


def draw_dag(ax: Axes, spec: str, label: str) -> None:
    """Nodes as circles with the objectives' initials; edges as arrows named eta_i."""
    graph = ObjectiveGraph.parse(spec, 0.0, objectives=tuple(COLORS))
    names = graph.objectives
    sources = [n for n in names if not graph.parents(n)]
    if len(sources) == 1:  # a chain, left to right in topological order
        pos = {n: (i, 0.0) for i, n in enumerate(graph.order)}
    else:  # a fan: the sources above, the sink below
        pos = {n: (2.0 * i, 0.6) for i, n in enumerate(sources)}
        pos[graph.leaf] = (1.0, -0.6)
    for i, e in enumerate(graph.edges):
        (x0, y0), (x1, y1) = pos[e.parent], pos[e.child]
        ax.annotate("", xy=(x1, y1), xytext=(x0, y0),
                    arrowprops={"arrowstyle": "-|>", "shrinkA": 13, "shrinkB": 13, "lw": 1.2})
        ax.text((x0 + x1) / 2, (y0 + y1) / 2 + 0.18, rf"$\eta_{i + 1}$", ha="center",
                fontsize=9)
    for n, (x, y) in pos.items():
        ax.scatter([x], [y], s=520, facecolor="white", edgecolor=COLORS[n], linewidths=2,
                   zorder=3)
        ax.text(x, y, n[0].upper(), ha="center", va="center", fontsize=10, zorder=4)
    if label:
        ax.text(1.0, 1.3, f"({label})", ha="center", fontsize=11)
    ax.set_xlim(-0.6, 2.6)
    ax.set_ylim(-1.2, 1.6)
    ax.axis("off")


def draw_values(ax: Axes, record: dict[str, Any], xlabel: str) -> None:
    """Learned values (mean over seeds, min–max shaded) and LAR's (dashed)."""
    x = np.asarray(record["x"], float)
    lar = np.asarray(record["lar"])
    infeasible = ~np.asarray(record["feasible"], bool)
    for k, name in enumerate(record["objectives"]):
        color = COLORS.get(name, "black")
        if "exact" in record:  # else LAR's curve alone
            exact = np.asarray(record["exact"])[:, :, k]
            ax.plot(x, exact.mean(axis=1), color=color, lw=2, marker="o", ms=3,
                    label=f"V_{name}")
            ax.fill_between(x, exact.min(axis=1), exact.max(axis=1), color=color, alpha=0.15,
                            lw=0)
        ax.plot(x, lar[:, k], color=color, lw=1.2, ls="--", marker="." if len(x) == 1 else "",
                label=None if "exact" in record else f"LAR V_{name}")
        if infeasible.any():
            ax.plot(x[infeasible], lar[infeasible, k], "x", color="black", ms=6)
    ax.set_xscale("symlog", linthresh=1.0)
    if len(x) > 1:
        ax.set_xlim(x.min(), x.max())
    ax.set_xlabel(xlabel)
    ax.set_ylabel("V (discounted, start state)")
    ax.grid(True, color="lightgray", lw=0.5)


def figure2(records: Sequence[dict[str, Any]], panels: Sequence[Any]) -> Figure:
    """Two rows of two panels, each a DAG drawing beside its value plot."""
    fig = Figure(figsize=(13, 6.5))
    grid = fig.add_gridspec(2, 4, width_ratios=[1, 2.3, 1, 2.3])
    for i, (record, panel) in enumerate(zip(records, panels, strict=True)):
        row, col = divmod(i, 2)
        draw_dag(fig.add_subplot(grid[row, 2 * col]), panel.dag, panel.name)
        ax = fig.add_subplot(grid[row, 2 * col + 1])
        draw_values(ax, record, panel.xlabel)
        if i == 0:
            ax.legend(fontsize=8, loc="best")
    fig.suptitle("Learned greedy policy (solid, seed min–max shaded) and LAR (dashed, "
                 "x = infeasible, relaxed) against slack", fontsize=10)
    fig.tight_layout()
    return fig


def sweep_figure(record: dict[str, Any], dag: str, xlabel: str, title: str) -> Figure:
    """One DAG drawing beside its values against slack: learned (if ``record`` has
    them) solid with the seeds' range shaded, LAR dashed."""
    fig = Figure(figsize=(8.5, 3.8))
    grid = fig.add_gridspec(1, 2, width_ratios=[1, 2.3])
    draw_dag(fig.add_subplot(grid[0, 0]), dag, "")
    ax = fig.add_subplot(grid[0, 1])
    draw_values(ax, record, xlabel)
    ax.legend(fontsize=8, loc="best")
    ax.set_title(title, fontsize=10)
    fig.tight_layout()
    return fig
