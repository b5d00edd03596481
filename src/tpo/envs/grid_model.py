"""The exact tabular model of a navigation map (docs/design.md §3).

States are the map's free cells (row-major), actions up, down, left, right.
A move into a wall or off the grid is a *bump*: the robot stays. With ``slip``
the robot moves in a uniformly random *other* direction with that probability.
Rewards are paid on the state where the step starts (expected over the slip):

    goal     -1 every step (the goal cell is terminal)
    avoid    -1 inside an avoid rectangle, -1 more on a bump
    monitor  +1 inside a monitor rectangle, -1 on a bump
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tpo.envs.maps import OBJECTIVES, NavMap
from tpo.errors import MapError
from tpo.tabular import TabularTMDP

ACTIONS = ("up", "down", "left", "right")
MOVES = np.array([(-1, 0), (1, 0), (0, -1), (0, 1)])


def slip_matrix(slip: float) -> np.ndarray:
    """``P[a, d]``: probability that action ``a`` moves in direction ``d``."""
    if isinstance(slip, bool) or not isinstance(slip, (int, float)) or not 0 <= slip <= 1:
        raise MapError(f"slip must be a probability in [0, 1], got {slip!r}")
    n = len(ACTIONS)
    return np.where(np.eye(n, dtype=bool), 1.0 - slip, slip / (n - 1))


@dataclass(frozen=True, eq=False)
class GridModel:
    """A map's exact model with the cell of every state.

    Attributes:
        navmap: the map.
        model: the finite TMDP (objectives ``goal, avoid, monitor``).
        cells: int ``[S, 2]``, the ``(row, col)`` of every state.
        index: int ``[H, W]``, the state of every cell (-1 on walls).
    """

    navmap: NavMap
    model: TabularTMDP
    cells: np.ndarray
    index: np.ndarray

    def rollout(self, policy: np.ndarray, steps: int | None = None) -> np.ndarray:
        """Cells ``[T, 2]`` visited by a deterministic policy from the start, without
        slip, until the goal or ``steps`` (default the map's ``max_steps``)."""
        state = self.model.start
        path = [state]
        for _ in range(self.navmap.max_steps if steps is None else steps):
            if self.model.terminal[state]:
                break
            state = self._intended(state, int(policy[state]))
            path.append(state)
        return self.cells[path]

    def _intended(self, state: int, action: int) -> int:
        r, c = self.cells[state] + MOVES[action]
        h, w = self.index.shape
        inside = 0 <= r < h and 0 <= c < w and self.index[r, c] >= 0
        return int(self.index[r, c]) if inside else state


def grid_model(navmap: NavMap, gamma: float = 0.99, slip: float = 0.0) -> GridModel:
    """The exact model of ``navmap`` with discount ``gamma`` and slip probability ``slip``."""
    free = ~navmap.walls
    cells = np.argwhere(free)
    index = np.full(navmap.shape, -1)
    index[free] = np.arange(len(cells))
    h, w = navmap.shape
    target = cells[:, None, :] + MOVES[None, :, :]  # [S, D, 2]
    inside = (target[..., 0] >= 0) & (target[..., 0] < h) & (target[..., 1] >= 0) \
        & (target[..., 1] < w)
    clipped = np.clip(target, 0, [h - 1, w - 1])
    bump = ~inside | navmap.walls[clipped[..., 0], clipped[..., 1]]
    moved = np.where(bump, np.arange(len(cells))[:, None],
                     index[clipped[..., 0], clipped[..., 1]])  # [S, D]
    p = slip_matrix(slip)  # [A, D]
    if slip == 0:
        successors, probs = moved[:, :, None], np.ones((len(cells), len(ACTIONS), 1))
    else:
        successors = np.broadcast_to(moved[:, None, :], (len(cells), len(ACTIONS), len(ACTIONS)))
        probs = np.broadcast_to(p[None], successors.shape)
    bump_rate = bump.astype(float) @ p.T  # [S, A] expected bumps
    in_avoid = navmap.avoid_mask[free].astype(float)[:, None]
    in_monitor = navmap.monitor_mask[free].astype(float)[:, None]
    rewards = np.stack([-np.ones_like(bump_rate), -in_avoid - bump_rate,
                        in_monitor - bump_rate], axis=-1)
    terminal = np.zeros(len(cells), bool)
    terminal[index[navmap.goal]] = True
    rewards[terminal] = 0.0
    model = TabularTMDP(successors, probs, rewards, OBJECTIVES, gamma=gamma,
                        start=int(index[navmap.start]), terminal=terminal)
    return GridModel(navmap, model, cells, index)
