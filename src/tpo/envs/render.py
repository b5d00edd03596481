"""Drawing maps and trajectories with matplotlib, as the paper's Figure 3 draws paths."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle

from tpo.envs.maps import NavMap

AVOID_COLOR = "#f4a6a6"
MONITOR_COLOR = "#a6c8f4"
PATH_COLORS = ("tab:blue", "tab:red", "tab:green", "tab:purple", "tab:orange")


def draw_map(ax: Axes, navmap: NavMap) -> None:
    """Walls, avoid (red) and monitor (blue) regions, start ``S`` and goal ``G``."""
    h, w = navmap.shape
    ax.imshow(np.where(navmap.walls, 0.15, 1.0), cmap="gray", vmin=0, vmax=1,
              extent=(-0.5, w - 0.5, h - 0.5, -0.5), interpolation="nearest")
    for rects, color, label in ((navmap.avoid, AVOID_COLOR, "avoid"),
                                (navmap.monitor, MONITOR_COLOR, "monitor")):
        for i, (r0, c0, r1, c1) in enumerate(rects):
            ax.add_patch(Rectangle((c0 - 0.5, r0 - 0.5), c1 - c0 + 1, r1 - r0 + 1,
                                   facecolor=color, alpha=0.6, edgecolor="none",
                                   label=label if i == 0 else None))
    for (r, c), text in ((navmap.start, "S"), (navmap.goal, "G")):
        ax.text(c, r, text, ha="center", va="center", fontsize=11, fontweight="bold")
    ax.set_xticks([])
    ax.set_yticks([])


def draw_path(ax: Axes, cells: np.ndarray, color: str, label: str | None = None,
              offset: float = 0.0) -> None:
    """A trajectory of ``(row, col)`` cells; ``offset`` shifts it so paths stay apart."""
    cells = np.asarray(cells, dtype=float)
    ax.plot(cells[:, 1] + offset, cells[:, 0] + offset, color=color, linewidth=2.5,
            alpha=0.9, label=label, solid_capstyle="round")


def plot_paths(navmap: NavMap, paths: Sequence[np.ndarray], labels: Sequence[str] = (),
               colors: Sequence[str] = PATH_COLORS, title: str | None = None) -> Figure:
    """A figure of the map with the given paths."""
    h, w = navmap.shape
    fig, ax = plt.subplots(figsize=(max(4.0, w * 0.28), max(3.0, h * 0.28 + 0.6)))
    draw_map(ax, navmap)
    n = len(paths)
    for i, cells in enumerate(paths):
        offset = 0.15 * (i - (n - 1) / 2)
        draw_path(ax, cells, colors[i % len(colors)], labels[i] if i < len(labels) else None,
                  offset)
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.01), ncol=2 + n, frameon=False,
              fontsize=8)
    if title:
        ax.set_title(title, fontsize=10)
    fig.tight_layout()
    return fig


def save_figure(fig: Figure, path: str | Path) -> Path:
    """Save ``fig`` (PNG, PDF or SVG by suffix), creating parent folders."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=150)
    plt.close(fig)
    return path
