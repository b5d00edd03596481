"""Continuous-space navigation on the same maps, as a pure JAX environment.

The robot is a point at a continuous ``(row, col)`` position; cell ``(r, c)``
covers ``[r, r + 1) x [c, c + 1)`` and it starts at the centre of the map's
start cell. An action moves it by at most ``speed`` cells:

- ``"velocity"``: a 2-vector in ``[-1, 1]^2`` (``(d_row, d_col)``, scaled down
  to unit length if longer), times ``speed``;
- ``"heading"``: one of 8 compass headings (0 = up, clockwise), at ``speed``.

A move that would end in a wall, off the grid, or cut a wall's corner is a
*bump*: the robot stays. Optional Gaussian ``noise`` perturbs every move.
Rewards follow the grid's per-step semantics on the cell where the step
starts (goal -1; avoid -1 inside, -1 per bump; monitor +1 inside, -1 per bump)
and entering the goal cell ends the episode.

``random_start=True`` starts episodes at a uniformly random point of a uniformly
random non-goal free cell (exploring starts for training, as the grid's);
otherwise at the centre of the map's start cell.

Observations (:func:`tpo.sensing.observation`, ``4 + n_beams`` numbers): the
position scaled to ``[0, 1]``, ``n_beams`` range readings to the nearest wall
along evenly spaced directions (divided by ``max_range``), in-avoid and
in-monitor flags; ``observation="factored"`` (the default) appends ``H + W``
tents of the position about every row's and column's centre
(:func:`tpo.sensing.cell_features`, the grid's factored one-hots made
continuous), ``"coords"`` leaves them out. Measured on ``home`` (velocity
actions, ``M>A>G`` at slack 0, 5 seeds): the learned monitor value 61.1-61.7
with them against 59.9-60.5 without, the reference's 62.7
(docs/notes/tpo-learning.md, session 16). ``"factored+onehot"`` appends ``H * W``
tents about every cell's centre after them (:func:`tpo.sensing.place_features`,
the grid's cell one-hot made continuous), so that no place is valued by its
column alone (session 39). ``"auto"`` is ``"factored+onehot"`` on maps of at most
:data:`PLACE_CELLS` cells (``H * W``, walls included: the cell tents are a dense
first layer's inputs) and ``"factored"`` on larger ones; the env records the kind it
chose (:attr:`ContinuousNav.observation`).
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from tpo.envs.base import JaxEnv, nav_reward
from tpo.envs.maps import NavMap, check_max_steps
from tpo.errors import MapError
from tpo.sensing import blocked, observation, pad_walls, range_readings, ray_distances

ACTION_KINDS = ("velocity", "heading")
OBSERVATIONS = ("factored", "coords", "factored+onehot")
PLACE_CELLS = 1024  # "auto" adds the cell tents on maps of up to this many cells


def observation_kind(navmap: NavMap, kind: str) -> str:
    """``kind``, with ``"auto"`` resolved for ``navmap`` (module docstring)."""
    if kind == "auto":
        h, w = navmap.shape
        return "factored+onehot" if h * w <= PLACE_CELLS else "factored"
    if not isinstance(kind, str) or kind not in OBSERVATIONS:
        raise MapError(f"unknown continuous observation {kind!r:.40}; choose one of auto, "
                       f"{', '.join(OBSERVATIONS)}")
    return kind


def headings(n: int) -> np.ndarray:
    """``n`` unit vectors ``(d_row, d_col)``, clockwise from up."""
    angle = 2 * np.pi * np.arange(n) / n
    return np.stack([-np.cos(angle), np.sin(angle)], -1).astype(np.float32)


@struct.dataclass
class ContinuousParams:
    walls: jax.Array  # bool [H + 2, W + 2]: the walls in a border of walls (pad_walls)
    avoid: jax.Array  # bool [H, W]
    monitor: jax.Array  # bool [H, W]
    starts: jax.Array  # float32 [N, 2] the corner of every start cell
    jitter: jax.Array  # float32 [] 1 with random starts (anywhere in the cell), else 0
    goal: jax.Array  # int32 [2], the goal cell
    max_steps: jax.Array  # int32 []
    speed: jax.Array  # float32 []
    noise: jax.Array  # float32 []
    beams: jax.Array  # float32 [K, 2] sensor directions
    ray_t: jax.Array  # float32 [M] distances sampled along a beam
    factored: bool = struct.field(pytree_node=False)  # + cell_features (static: a shape)
    places: bool = struct.field(pytree_node=False)  # + place_features


@struct.dataclass
class ContinuousState:
    pos: jax.Array  # float32 [2]
    time: jax.Array  # int32 []


class ContinuousNav(JaxEnv):
    """Continuous navigation with vector rewards ``[goal, avoid, monitor]``."""

    def __init__(self, navmap: NavMap, action: str = "velocity", speed: float = 0.5,
                 noise: float = 0.0, n_beams: int = 8, max_range: float = 6.0,
                 max_steps: int | None = None, random_start: bool = False,
                 observation: str = "factored") -> None:
        if action not in ACTION_KINDS:
            raise MapError(f"unknown action kind '{action}'; choose velocity or heading")
        observation = observation_kind(navmap, observation)
        if not 0 < speed <= 1:
            raise MapError(f"speed must be in (0, 1] cells per step, got {speed}")
        if noise < 0 or not np.isfinite(noise):
            raise MapError(f"noise must be a finite number >= 0, got {noise}")
        if n_beams < 1 or max_range <= 0:
            raise MapError("a range sensor needs n_beams >= 1 and max_range > 0")
        steps = check_max_steps(int(np.ceil(navmap.max_steps / speed)) if max_steps is None
                                else max_steps)
        self.navmap, self.action, self.max_range = navmap, action, float(max_range)
        self.random_start = random_start
        self.action_space = (gym.spaces.Discrete(8) if action == "heading"
                             else gym.spaces.Box(-1.0, 1.0, (2,), np.float32))
        self.params = ContinuousParams(
            walls=jnp.asarray(pad_walls(navmap.walls)), avoid=jnp.asarray(navmap.avoid_mask),
            monitor=jnp.asarray(navmap.monitor_mask),
            starts=jnp.asarray(navmap.start_cells(random_start), jnp.float32),
            jitter=jnp.float32(random_start),
            goal=jnp.asarray(navmap.goal, jnp.int32), max_steps=jnp.asarray(steps, jnp.int32),
            speed=jnp.float32(speed), noise=jnp.float32(noise),
            beams=jnp.asarray(headings(n_beams)),
            ray_t=jnp.asarray(ray_distances(max_range)),
            factored=observation != "coords", places=observation == "factored+onehot")

    @property
    def observation(self) -> str:
        """The observation's kind (one of :data:`OBSERVATIONS`)."""
        if self.params.places:
            return "factored+onehot"
        return "factored" if self.params.factored else "coords"

    @property
    def obs_shape(self) -> tuple[int]:
        h, w = self.navmap.shape
        cells = (h + w) * self.params.factored + h * w * self.params.places
        return (4 + int(self.params.beams.shape[0]) + cells,)

    def to_spec(self) -> dict[str, Any]:
        """What rebuilds this env (:func:`tpo.envs.from_spec`); the map travels as
        TOML text."""
        return {"kind": "continuous", "map": self.navmap.to_toml(), "action": self.action,
                "speed": float(self.params.speed), "noise": float(self.params.noise),
                "n_beams": int(self.params.beams.shape[0]), "max_range": self.max_range,
                "max_steps": int(self.params.max_steps), "random_start": self.random_start,
                "observation": self.observation}

    # ------------------------------------------------------------ pure JAX API
    @staticmethod
    def reset(key: jax.Array, params: ContinuousParams) -> tuple[jax.Array, ContinuousState]:
        """The first observation and state of an episode: the centre of the map's
        start cell, or with ``random_start`` a random point of a random start cell."""
        k_cell, k_point = jax.random.split(key)
        corner = params.starts[jax.random.randint(k_cell, (), 0, params.starts.shape[0])]
        offset = 0.5 + params.jitter * (jax.random.uniform(k_point, (2,)) * 0.98 - 0.49)
        state = ContinuousState(pos=corner + offset, time=jnp.zeros((), jnp.int32))
        return ContinuousNav.observe(state, params), state

    @staticmethod
    def observe(state: ContinuousState, params: ContinuousParams) -> jax.Array:
        """:func:`tpo.sensing.observation` of the robot's position."""
        distances = range_readings(state.pos, params.walls, params.beams, params.ray_t, jnp)
        return observation(state.pos, distances, params.avoid, params.monitor,
                           params.ray_t[-1], jnp, params.factored, params.places)

    @staticmethod
    def displacement(action: jax.Array, params: ContinuousParams) -> jax.Array:
        """The intended move of an action: heading index (scalar int) or velocity [2]."""
        if jnp.ndim(action) == 0:
            return jnp.asarray(headings(8))[action] * params.speed
        v = jnp.clip(jnp.asarray(action, jnp.float32), -1.0, 1.0)
        return v / jnp.maximum(1.0, jnp.linalg.norm(v)) * params.speed

    @staticmethod
    def step_env(key: jax.Array, state: ContinuousState, action: jax.Array,
                 params: ContinuousParams
                 ) -> tuple[jax.Array, ContinuousState, jax.Array, jax.Array, jax.Array]:
        """One step without auto-reset: ``(obs, state, reward[3], terminated, truncated)``."""
        move = ContinuousNav.displacement(action, params)
        move = move + params.noise * jax.random.normal(key, (2,))
        target = state.pos + move
        here = jnp.floor(state.pos)
        there = jnp.floor(target)
        corners = jnp.stack([target, jnp.stack([there[0], here[1]]) + 0.5,
                             jnp.stack([here[0], there[1]]) + 0.5])
        bump = blocked(corners, params.walls, jnp).any()
        pos = jnp.where(bump, state.pos, target)
        reward = nav_reward(params.avoid, params.monitor, here.astype(jnp.int32), bump)
        time = state.time + 1
        terminated = jnp.all(jnp.floor(pos).astype(jnp.int32) == params.goal)
        truncated = (time >= params.max_steps) & ~terminated
        nxt = ContinuousState(pos=pos, time=time)
        return ContinuousNav.observe(nxt, params), nxt, reward, terminated, truncated

