"""Run an exported tpo policy with NumPy alone: no JAX, no Flax, no Gymnasium.

A robot's loop is position → observation → action::

    from tpo.deploy import load_policy

    policy = load_policy("policy.npz")            # written by `tpo export RUN --format npz`
    obs = policy.observer.observe(cell=(3, 4))     # grid maps: the robot's cell
    obs = policy.observer.observe(position=(3.5, 4.2), ranges=readings)  # continuous maps
    action = policy.act(obs)                       # greedy: an action index, or a velocity

``policy.meta`` says what the policy expects and does (observation kind, action
meanings, map name and hash, objectives, DAG, slack, gamma, tpo version). The
file's arrays: the actor's layers ``layer_<i>/kernel``, ``layer_<i>/bias``,
``out/kernel``, ``out/bias`` (and ``log_std`` for a Gaussian), the observer's
arrays under ``observer/``, and ``meta`` (JSON text).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from tpo import sensing

FORMAT = 1  # of the exported file
ACTIVATIONS = {"tanh": np.tanh, "relu": lambda x: np.maximum(x, 0.0)}


class DeployError(ValueError):
    """An exported policy file that cannot be used, or an observation that does not fit."""


@dataclass(frozen=True)
class GridObserver:
    """The observation of a grid map's cell: a row of the exported table ``[H, W, D]``."""

    table: np.ndarray

    def observe(self, cell: tuple[int, int]) -> np.ndarray:
        """The observation ``float32 [D]`` of the robot at ``cell`` (row, col)."""
        r, c = (int(v) for v in cell)
        h, w = self.table.shape[:2]
        if not (0 <= r < h and 0 <= c < w):
            raise DeployError(f"cell {(r, c)} is off the {h} x {w} map")
        return self.table[r, c]


@dataclass(frozen=True)
class ContinuousObserver:
    """The continuous map's observation (:func:`tpo.sensing.observation`): the robot's
    position and its range readings; :meth:`ranges` gives a perfect sensor's on the
    exported map (for simulation, or where the robot has no range sensor)."""

    walls: np.ndarray
    avoid: np.ndarray
    monitor: np.ndarray
    beams: np.ndarray  # [K, 2] sensor directions (d_row, d_col), clockwise from up
    ray_t: np.ndarray  # [M] distances sampled along a beam

    @property
    def max_range(self) -> float:
        return float(self.ray_t[-1])

    def ranges(self, position: Any) -> np.ndarray:
        """A perfect range sensor's readings ``[K]`` at ``position`` on the map."""
        return sensing.range_readings(self._position(position), self.walls, self.beams,
                                      self.ray_t)

    def observe(self, position: Any, ranges: Any | None = None) -> np.ndarray:
        """The observation ``float32 [4 + K]`` at ``position`` (row, col in cells) with
        the robot's own ``ranges [K]`` (cells; by default :meth:`ranges`)."""
        pos = self._position(position)
        readings = self.ranges(pos) if ranges is None else np.asarray(ranges, np.float32)
        if readings.shape != (len(self.beams),):
            raise DeployError(f"ranges must be {len(self.beams)} readings, got shape "
                              f"{readings.shape}")
        readings = np.minimum(readings, np.float32(self.max_range))
        return sensing.observation(pos, readings, self.avoid, self.monitor,
                                   np.float32(self.max_range))

    def _position(self, position: Any) -> np.ndarray:
        pos = np.asarray(position, np.float32)
        h, w = self.walls.shape
        if pos.shape != (2,) or not np.all(np.isfinite(pos)) \
                or not (0 <= pos[0] < h and 0 <= pos[1] < w):
            raise DeployError(f"position must be (row, col) on the {h} x {w} map, got "
                              f"{position!r}")
        return pos


@dataclass(frozen=True)
class Policy:
    """An exported actor: an MLP whose output is a categorical policy's logits or a
    Gaussian's mean; :meth:`act` is its greedy action."""

    layers: tuple[tuple[np.ndarray, np.ndarray], ...]  # (kernel [in, out], bias [out])
    activation: str
    log_std: np.ndarray | None  # a Gaussian's; None for discrete actions
    meta: dict[str, Any]
    observer: GridObserver | ContinuousObserver | None

    @property
    def discrete(self) -> bool:
        return self.log_std is None

    @property
    def obs_size(self) -> int:
        return self.layers[0][0].shape[0]

    def forward(self, obs: Any) -> np.ndarray:
        """The logits (discrete) or the mean (continuous) at ``obs [..., D]``."""
        x = np.asarray(obs, np.float32)
        if x.shape[-1:] != (self.obs_size,):
            raise DeployError(f"an observation has {self.obs_size} numbers, got shape "
                              f"{x.shape}")
        act = ACTIVATIONS[self.activation]
        *hidden, (kernel, bias) = self.layers
        for w, b in hidden:
            x = act(x @ w + b)
        return x @ kernel + bias

    def act(self, obs: Any) -> np.ndarray:
        """The greedy action at ``obs [..., D]``: the most likely action's index, or the
        Gaussian's mean (the env clips a velocity to ``[-1, 1]`` and unit length)."""
        out = self.forward(obs)
        return np.argmax(out, axis=-1) if self.discrete else out


def load_policy(path: str | Path) -> Policy:
    """The policy of an exported ``.npz`` (``tpo export RUN --format npz``)."""
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {k: data[k] for k in data.files}
        meta = json.loads(str(arrays.pop("meta")))
    except (OSError, ValueError, KeyError) as err:
        raise DeployError(f"{path} is not an exported tpo policy: {err}") from None
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        raise DeployError(f"{path}: unknown export format "
                          f"{meta.get('format') if isinstance(meta, dict) else None!r} "
                          f"(this version reads {FORMAT})")
    try:
        n_hidden = len(meta["hidden"])
        names = [f"layer_{i}" for i in range(n_hidden)] + ["out"]
        layers = tuple((arrays[f"{n}/kernel"], arrays[f"{n}/bias"]) for n in names)
        observer = _observer(meta["observation"]["kind"], arrays)
        activation = meta["activation"]
    except KeyError as err:
        raise DeployError(f"{path} lacks {err} (a damaged or foreign file)") from None
    if activation not in ACTIVATIONS:
        raise DeployError(f"{path}: unknown activation {activation!r}")
    return Policy(layers, activation, arrays.get("log_std"), meta, observer)


def _observer(kind: str, arrays: dict[str, np.ndarray]
              ) -> GridObserver | ContinuousObserver | None:
    if kind == "continuous":
        return ContinuousObserver(*(arrays[f"observer/{n}"] for n in
                                    ("walls", "avoid", "monitor", "beams", "ray_t")))
    if kind in ("factored", "onehot", "coords"):
        return GridObserver(arrays["observer/table"])
    return None  # an env of the user's own: its observations are the env's
