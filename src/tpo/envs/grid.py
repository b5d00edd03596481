"""The navigation grid as a pure JAX environment (gymnax style).

``reset(key, params)`` and ``step(key, state, action, params)`` are pure
functions over :class:`GridState` and :class:`GridParams` dataclasses, so they
jit, vmap and scan. ``step`` auto-resets: when an episode ends it returns the
first observation of the next one and keeps the true last observation in
``info["final_obs"]`` (needed to bootstrap at truncation). ``step_env`` is the
step without the reset. The dynamics and rewards are those of
:mod:`tpo.envs.grid_model`, whose exact model has the same state order as
:meth:`GridNav.tabular_observations`.

Observations are looked up in a per-map table ``[H, W, D]`` (one gather per
step). Four encodings (see :data:`OBSERVATIONS`):

- ``"factored"``: one-hot row + one-hot column + the four neighbour walls +
  in-avoid + in-monitor, ``H + W + 6`` numbers. Sharp per-row/column features
  that an MLP combines into cells, growing with ``H + W``, not ``H * W``.
- ``"onehot"``: one-hot cell, ``H * W`` numbers (learns reliably, scales badly).
- ``"coords"``: row and column in ``[0, 1]`` + walls + region flags, 8 numbers.
- ``"factored+onehot"``: the factored numbers, then a one-hot of the free cell
  (``H + W + 6 + F`` numbers for ``F`` free cells): the row and column features
  generalize across a room, the cell's own number lets a small MLP draw a value
  that changes at a wall (the held-out maps' detours, docs/notes).

``"auto"`` (the default) is ``"factored+onehot"`` on maps of at most
:data:`ONEHOT_CELLS` free cells and ``"factored"`` on larger ones; the env
records the kind it chose (:attr:`GridNav.observation`).

``benchmarks/bench_observations.py`` measured which of them PPO learns from
(README, "Observations"). ``random_start=True`` starts episodes in a uniformly
random non-goal free cell: an exploring-starts training distribution (every
state is visited, so critics are fit everywhere); LAR's policies are optimal at
every state, so it does not change what is learned, only how fast.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from tpo.envs.base import JaxEnv, nav_reward
from tpo.envs.grid_model import MOVES, GridModel, grid_model, slip_matrix
from tpo.envs.maps import NavMap, check_max_steps
from tpo.errors import MapError

OBSERVATIONS = ("factored", "onehot", "coords", "factored+onehot")
ONEHOT_CELLS = 4096  # "auto" adds the free cell's one-hot up to this many free cells


@struct.dataclass
class GridParams:
    """Static map data and dynamics of one navigation grid (arrays, not traced shapes)."""

    walls: jax.Array  # bool [H, W]
    avoid: jax.Array  # bool [H, W]
    monitor: jax.Array  # bool [H, W]
    obs_table: jax.Array  # float32 [H, W, D]
    start: jax.Array  # int32 [2]
    goal: jax.Array  # int32 [2]
    max_steps: jax.Array  # int32 []
    slip: jax.Array  # float32 []
    starts: jax.Array  # int32 [N, 2], cells an episode may start in


@struct.dataclass
class GridState:
    pos: jax.Array  # int32 [2], (row, col)
    time: jax.Array  # int32 [], steps taken in this episode


def observation_kind(navmap: NavMap, kind: str) -> str:
    """``kind``, with ``"auto"`` resolved for ``navmap`` (module docstring)."""
    if kind == "auto":
        return "factored+onehot" if (~navmap.walls).sum() <= ONEHOT_CELLS else "factored"
    if not isinstance(kind, str) or kind not in OBSERVATIONS:
        raise MapError(f"unknown observation {kind!r:.40}; choose one of auto, "
                       f"{', '.join(OBSERVATIONS)}")
    return kind


def observation_table(navmap: NavMap, kind: str = "auto") -> np.ndarray:
    """The observation of every cell, ``float32 [H, W, D]``."""
    kind = observation_kind(navmap, kind)
    h, w = navmap.shape
    rows, cols = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
    padded = np.pad(navmap.walls, 1, constant_values=True)
    walls = np.stack([padded[1 + dr:1 + dr + h, 1 + dc:1 + dc + w] for dr, dc in MOVES], -1)
    flags = np.stack([navmap.avoid_mask, navmap.monitor_mask], -1)
    factored = [np.eye(h)[rows], np.eye(w)[cols], walls, flags]
    if kind == "factored":
        parts = factored
    elif kind == "onehot":
        parts = [np.eye(h * w)[rows * w + cols]]
    elif kind == "coords":
        parts = [np.stack([rows / max(h - 1, 1), cols / max(w - 1, 1)], -1), walls, flags]
    else:
        free = ~navmap.walls
        cell = np.zeros((h, w, int(free.sum())))
        cell[free, np.arange(cell.shape[-1])] = 1.0
        parts = [*factored, cell]
    return np.concatenate(parts, axis=-1).astype(np.float32)


class GridNav(JaxEnv):
    """The multi-objective navigation grid of a map.

    Rewards are vectors ``[goal, avoid, monitor]``; actions up, down, left, right.
    """

    def __init__(self, navmap: NavMap, slip: float = 0.0, observation: str = "auto",
                 max_steps: int | None = None, random_start: bool = False) -> None:
        slip_matrix(slip)  # validates
        self.navmap = navmap
        self.observation = observation_kind(navmap, observation)
        table = observation_table(navmap, self.observation)
        steps = check_max_steps(navmap.max_steps if max_steps is None else max_steps)
        self.random_start = random_start
        self.action_space = gym.spaces.Discrete(len(MOVES))
        self.params = GridParams(
            walls=jnp.asarray(navmap.walls), avoid=jnp.asarray(navmap.avoid_mask),
            monitor=jnp.asarray(navmap.monitor_mask), obs_table=jnp.asarray(table),
            start=jnp.asarray(navmap.start, jnp.int32), goal=jnp.asarray(navmap.goal, jnp.int32),
            max_steps=jnp.asarray(steps, jnp.int32), slip=jnp.asarray(slip, jnp.float32),
            starts=jnp.asarray(navmap.start_cells(random_start), jnp.int32))

    @property
    def obs_shape(self) -> tuple[int]:
        return (int(self.params.obs_table.shape[-1]),)

    @property
    def observation_views(self) -> tuple[np.ndarray, ...]:
        """Parts of the observation that a learner may see alone (bool masks ``[D]``):
        of ``"factored+onehot"``, the free cell's one-hot, then the factored numbers;
        none of the other kinds (a population's members learn from them in turn:
        :class:`tpo.algo.TPO`)."""
        if self.observation != "factored+onehot":
            return ()
        factored = np.arange(self.obs_shape[0]) < self._factored_size
        return ~factored, factored

    @property
    def observation_onehots(self) -> tuple[tuple[int, int], ...]:
        """The blocks ``(start, stop)`` of the observation that hold at most one 1
        (the row's and the column's one-hots, the free cell's, all zero at a wall):
        a network reads each as a row of its first layer, not a product
        (:class:`tpo.algo.networks.InputDense`)."""
        h, w = self.navmap.shape
        factored = ((0, h), (h, h + w))
        return {"factored": factored, "onehot": ((0, h * w),), "coords": (),
                "factored+onehot": (*factored, (self._factored_size, self.obs_shape[0]))
                }[self.observation]

    @property
    def _factored_size(self) -> int:
        """How many numbers the factored part of the observation is (``H + W + 6``)."""
        h, w = self.navmap.shape
        return h + w + len(MOVES) + 2

    def to_spec(self) -> dict[str, Any]:
        """What rebuilds this env (:func:`tpo.envs.from_spec`); the map travels as
        TOML text."""
        return {"kind": "grid", "map": self.navmap.to_toml(), "slip": float(self.params.slip),
                "observation": self.observation, "max_steps": int(self.params.max_steps),
                "random_start": self.random_start}

    # ------------------------------------------------------------ pure JAX API
    @staticmethod
    def reset(key: jax.Array, params: GridParams) -> tuple[jax.Array, GridState]:
        """The first observation and state of an episode: the map's start, or a
        uniformly random non-goal free cell with ``random_start``."""
        cell = params.starts[jax.random.randint(key, (), 0, params.starts.shape[0])]
        state = GridState(pos=cell, time=jnp.zeros((), jnp.int32))
        return GridNav.observe(state, params), state

    @staticmethod
    def observe(state: GridState, params: GridParams) -> jax.Array:
        return params.obs_table[state.pos[0], state.pos[1]]

    @staticmethod
    def _slip(key: jax.Array, action: jax.Array, slip: jax.Array) -> jax.Array:
        """With probability ``slip`` a uniformly random other direction."""
        bits = jax.random.bits(key, (2,))
        slipped = bits[0] < slip * 2.0**32
        return jnp.where(slipped, (action + 1 + bits[1] % 3) % 4, action)

    @staticmethod
    def step_env(key: jax.Array, state: GridState, action: jax.Array, params: GridParams
                 ) -> tuple[jax.Array, GridState, jax.Array, jax.Array, jax.Array]:
        """One step without auto-reset: ``(obs, state, reward[3], terminated, truncated)``."""
        action = jnp.asarray(action, jnp.int32)
        direction = jax.lax.cond(params.slip > 0, GridNav._slip, lambda *_: action,
                                 key, action, params.slip)
        target = state.pos + jnp.asarray(MOVES, jnp.int32)[direction]
        h, w = params.walls.shape
        inside = (target[0] >= 0) & (target[0] < h) & (target[1] >= 0) & (target[1] < w)
        clipped = jnp.clip(target, 0, jnp.array([h - 1, w - 1]))
        bump = ~inside | params.walls[clipped[0], clipped[1]]
        pos = jnp.where(bump, state.pos, clipped)
        reward = nav_reward(params.avoid, params.monitor, state.pos, bump)
        time = state.time + 1
        terminated = jnp.all(pos == params.goal)
        truncated = (time >= params.max_steps) & ~terminated
        nxt = GridState(pos=pos, time=time)
        return GridNav.observe(nxt, params), nxt, reward, terminated, truncated

    # ------------------------------------------------------- exact evaluation
    def tabular(self, gamma: float = 0.99) -> GridModel:
        """The exact model of this environment (same map, slip and reward)."""
        return grid_model(self.navmap, gamma=gamma, slip=float(self.params.slip))

    def tabular_observations(self) -> np.ndarray:
        """``[S, D]``: the observation of every state of :meth:`tabular`'s model."""
        cells = np.argwhere(~self.navmap.walls)
        return np.asarray(self.params.obs_table)[cells[:, 0], cells[:, 1]]
