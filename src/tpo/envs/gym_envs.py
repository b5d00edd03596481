"""Gymnasium / MO-Gymnasium front ends of the JAX navigation environments.

The reward is a ``float32`` vector ``[goal, avoid, monitor]`` and the env has a
``reward_space`` (and ``reward_dim``), as MO-Gymnasium defines them, so
``mo_gymnasium`` wrappers such as ``LinearReward`` and
``MORecordEpisodeStatistics`` work. ``terminated`` and ``truncated`` are the
env's own (the time limit is the map's ``max_steps``). Registered ids, for
every bundled map ``NAME``:

- ``tpo/GridNav-NAME-v0``: the grid, 4 actions (``slip``, ``observation`` kwargs);
- ``tpo/ContinuousNav-NAME-v0``: continuous velocity actions in ``[-1, 1]^2``;
- ``tpo/ContinuousNavHeading-NAME-v0``: 8 discrete headings.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
from gymnasium import spaces

from tpo.envs.base import JaxGymEnv
from tpo.envs.continuous import ContinuousNav
from tpo.envs.grid import GridNav
from tpo.envs.maps import NavMap, load_map
from tpo.envs.render import draw_robot, raster


class NavEnv(JaxGymEnv):
    """A Gymnasium env stepping a pure JAX navigation env one transition at a time."""

    metadata: ClassVar[dict[str, Any]] = {"render_modes": ["rgb_array"], "render_fps": 10}
    CELL_PX = 12

    def __init__(self, jax_env: GridNav | ContinuousNav, observation_space: spaces.Box,
                 action_space: spaces.Space, render_mode: str | None = None) -> None:
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        super().__init__(jax_env, observation_space, action_space)
        self.navmap: NavMap = jax_env.navmap
        self.render_mode = render_mode
        self._background = raster(self.navmap, self.CELL_PX)

    def render(self) -> np.ndarray | None:
        if self.render_mode != "rgb_array":
            return None
        if self._state is None:
            return self._background.copy()
        return draw_robot(self._background, self._robot_position(), self.CELL_PX)

    def _robot_position(self) -> np.ndarray:
        return np.asarray(self._state.pos, dtype=float)


class GridNavEnv(NavEnv):
    """``tpo/GridNav-*``: the navigation grid."""

    def __init__(self, map: str = "home", slip: float = 0.0, observation: str = "auto",
                 max_steps: int | None = None, random_start: bool = False,
                 render_mode: str | None = None) -> None:
        env = GridNav(load_map(map), slip=slip, observation=observation, max_steps=max_steps,
                      random_start=random_start)
        table = np.asarray(env.params.obs_table)
        box = spaces.Box(table.min(), table.max(), env.obs_shape, np.float32)
        super().__init__(env, box, env.action_space, render_mode)

    def _robot_position(self) -> np.ndarray:
        return np.asarray(self._state.pos, dtype=float) + 0.5


class ContinuousNavEnv(NavEnv):
    """``tpo/ContinuousNav-*``: continuous position; velocity or heading actions."""

    def __init__(self, map: str = "home", action: str = "velocity", speed: float = 0.5,
                 noise: float = 0.0, n_beams: int = 8, max_range: float = 6.0,
                 max_steps: int | None = None, observation: str = "factored",
                 render_mode: str | None = None) -> None:
        env = ContinuousNav(load_map(map), action=action, speed=speed, noise=noise,
                            n_beams=n_beams, max_range=max_range, max_steps=max_steps,
                            observation=observation)
        box = spaces.Box(0.0, 1.0, env.obs_shape, np.float32)
        super().__init__(env, box, env.action_space, render_mode)

    def _jax_action(self, action: Any) -> Any:
        if isinstance(self.action_space, spaces.Discrete):
            return np.int32(action)
        return np.asarray(action, np.float32).reshape(2)
