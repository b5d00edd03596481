"""Drawing maps and trajectories: matplotlib figures (as the paper's Figure 3 draws
paths) and fast RGB rasters for Gymnasium's ``render_mode="rgb_array"``.

Figures are built on :class:`matplotlib.figure.Figure` directly, never through
pyplot, so drawing touches no global backend state.
"""

from __future__ import annotations

import io
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle

from tpo.atomic import write_atomic
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
    fig = Figure(figsize=(max(4.0, w * 0.28), max(3.0, h * 0.28 + 0.6)))
    ax = fig.add_subplot()
    draw_map(ax, navmap)
    n = len(paths)
    for i, cells in enumerate(paths):
        offset = 0.15 * (i - (n - 1) / 2)
        draw_path(ax, cells, colors[i % len(colors)], labels[i] if i < len(labels) else None,
                  offset)
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.01), ncol=2 + n if w >= 20 else 2,
              frameon=False, fontsize=8)
    if title:
        ax.set_title(title, fontsize=10)
    fig.tight_layout()
    return fig


def save_figure(fig: Figure, path: str | Path) -> Path:
    """Save ``fig`` (PNG, PDF or SVG by suffix), creating parent folders; the file
    is written whole or not at all."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    buffer = io.BytesIO()
    fig.savefig(buffer, format=path.suffix.lstrip(".").lower() or "png", dpi=150)
    write_atomic(path, buffer.getvalue())
    return path


RGB = {"wall": (40, 40, 40), "free": (255, 255, 255), "avoid": (244, 166, 166),
       "monitor": (166, 200, 244), "start": (200, 200, 200), "goal": (120, 200, 120),
       "robot": (20, 20, 20)}


def raster(navmap: NavMap, px: int = 12) -> np.ndarray:
    """The map as ``uint8 [H * px, W * px, 3]``: walls, regions, start and goal cells."""
    colors = np.empty((*navmap.shape, 3), np.uint8)
    colors[:] = RGB["free"]
    colors[navmap.avoid_mask] = RGB["avoid"]
    colors[navmap.monitor_mask] = RGB["monitor"]
    colors[navmap.start] = RGB["start"]
    colors[navmap.goal] = RGB["goal"]
    colors[navmap.walls] = RGB["wall"]
    return np.repeat(np.repeat(colors, px, axis=0), px, axis=1)


def draw_robot(image: np.ndarray, pos: np.ndarray, px: int = 12) -> np.ndarray:
    """A copy of ``image`` with the robot as a disc at continuous ``(row, col)``
    (cell ``(r, c)`` spans ``[r, r + 1) x [c, c + 1)``)."""
    out = image.copy()
    ys, xs = np.mgrid[0:image.shape[0], 0:image.shape[1]]
    centre = np.asarray(pos, dtype=float) * px
    disc = (ys + 0.5 - centre[0]) ** 2 + (xs + 0.5 - centre[1]) ** 2 <= (0.35 * px) ** 2
    out[disc] = RGB["robot"]
    return out
