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
from functools import cached_property
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
        """The observation ``float32 [D]`` (a copy) of the robot at ``cell`` (row, col)."""
        h, w = self.table.shape[:2]
        index = np.asarray(cell, dtype=object)
        if index.shape != (2,) or not all(
                isinstance(v, int | np.integer) and not isinstance(v, bool) for v in index):
            raise DeployError(f"cell must be two integers (row, col), got {cell!r}")
        r, c = (int(v) for v in index)
        if not (0 <= r < h and 0 <= c < w):
            raise DeployError(f"cell {(r, c)} is off the {h} x {w} map")
        return self.table[r, c].copy()


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
    factored: bool = False  # the observation ends with sensing.cell_features
    places: bool = False  # then with sensing.place_features

    @property
    def max_range(self) -> float:
        return float(self.ray_t[-1])

    def ranges(self, position: Any) -> np.ndarray:
        """A perfect range sensor's readings ``[K]`` at ``position`` on the map."""
        return sensing.range_readings(self._position(position), self._padded, self.beams,
                                      self.ray_t)

    @cached_property
    def _padded(self) -> np.ndarray:
        return sensing.pad_walls(self.walls)

    def observe(self, position: Any, ranges: Any | None = None) -> np.ndarray:
        """The observation ``float32 [4 + K]`` (``H + W`` more numbers when
        :attr:`factored`, then ``H * W`` when :attr:`places`) at ``position`` (row,
        col in cells) with the robot's own ``ranges [K]`` (cells; by default
        :meth:`ranges`)."""
        pos = self._position(position)
        readings = self.ranges(pos) if ranges is None else _numbers(ranges, "ranges")
        if readings.shape != (len(self.beams),) or not np.all(readings >= 0):
            raise DeployError(f"ranges must be {len(self.beams)} finite readings >= 0, got "
                              f"{np.asarray(ranges)!r:.80}")
        readings = np.minimum(readings, np.float32(self.max_range))  # the sensor's reach
        return sensing.observation(pos, readings, self.avoid, self.monitor,
                                   np.float32(self.max_range), factored=self.factored,
                                   places=self.places)

    def _position(self, position: Any) -> np.ndarray:
        pos = _numbers(position, "position", np.float64)
        h, w = self.walls.shape
        if pos.shape != (2,) or not (0 <= pos[0] < h and 0 <= pos[1] < w):
            raise DeployError(f"position must be (row, col) on the {h} x {w} map, got "
                              f"{position!r:.80}")
        # In float32 a position just below the map's edge may round onto it.
        return np.minimum(pos.astype(np.float32),
                          np.nextafter(np.array([h, w], np.float32), np.float32(0)))


@dataclass(frozen=True)
class Policy:
    """An exported actor: an MLP whose output is a categorical policy's logits, a
    Gaussian's mean, or a discretized continuous action's logits (``d`` dimensions of
    ``K`` values each, value ``k`` of dimension ``i`` being ``low_i + k step_i``);
    :meth:`act` is its greedy action."""

    layers: tuple[tuple[np.ndarray, np.ndarray], ...]  # (kernel [in, out], bias [out])
    activation: str
    log_std: np.ndarray | None  # a Gaussian's; else None
    meta: dict[str, Any]
    observer: GridObserver | ContinuousObserver | None
    values: tuple[np.ndarray, np.ndarray] | None = None  # a discretized action's (low, step)

    @property
    def discrete(self) -> bool:
        return self.log_std is None and self.values is None

    @property
    def obs_size(self) -> int:
        return self.layers[0][0].shape[0]

    def forward(self, obs: Any) -> np.ndarray:
        """The logits (discrete) or the mean (continuous) at ``obs [..., D]``."""
        x = _numbers(obs, "an observation")
        if x.shape[-1:] != (self.obs_size,):
            raise DeployError(f"an observation has {self.obs_size} numbers, got shape "
                              f"{x.shape}")
        act = ACTIVATIONS[self.activation]
        *hidden, (kernel, bias) = self.layers
        for w, b in hidden:
            x = act(x @ w + b)
        return x @ kernel + bias

    def act(self, obs: Any) -> np.ndarray:
        """The greedy action at ``obs [..., D]``: the most likely action's index, the
        Gaussian's mean (the env clips a velocity to ``[-1, 1]`` and unit length), or
        a discretized action's most likely value in each dimension."""
        out = self.forward(obs)
        if self.values is not None:
            low, step = self.values
            index = np.argmax(out.reshape(*out.shape[:-1], low.shape[0], -1), axis=-1)
            return (low + index * step).astype(np.float32)
        return np.argmax(out, axis=-1) if self.discrete else out


def load_policy(path: str | Path) -> Policy:
    """The policy of an exported ``.npz`` (``tpo export RUN --format npz``), checked
    whole: :class:`DeployError` if it is anything else or damaged."""
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {k: data[k] for k in data.files}
        meta = json.loads(str(arrays.pop("meta")))
    except Exception as err:  # a damaged zip raises what zipfile and numpy happen to
        hint = " (an .onnx file runs with ONNX Runtime)" if str(path).endswith(".onnx") else ""
        reason = "not a NumPy .npz of arrays" if "pickled" in str(err) else err
        raise DeployError(f"{path} is not an exported tpo policy{hint}: {reason}") from None
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        raise DeployError(f"{path}: unknown export format "
                          f"{meta.get('format') if isinstance(meta, dict) else None!r} "
                          f"(this version reads {FORMAT})")
    try:
        return _policy(arrays, meta)
    except (KeyError, TypeError, ValueError) as err:
        raise DeployError(f"{path} is damaged or not tpo's: {err}") from None


def _policy(arrays: dict[str, np.ndarray], meta: dict[str, Any]) -> Policy:
    hidden, activation = meta["hidden"], meta["activation"]
    if not isinstance(hidden, list) or activation not in ACTIVATIONS:
        raise ValueError(f"meta has hidden {hidden!r:.40} and activation {activation!r:.40}")
    names = [f"layer_{i}" for i in range(len(hidden))] + ["out"]
    layers = tuple((arrays.pop(f"{n}/kernel"), arrays.pop(f"{n}/bias")) for n in names)
    width = None
    for name, (kernel, bias) in zip(names, layers, strict=True):
        if kernel.dtype != np.float32 or bias.dtype != np.float32 or kernel.ndim != 2 \
                or bias.shape != kernel.shape[1:] or width not in (None, kernel.shape[0]):
            raise ValueError(f"layer {name} has kernel {kernel.shape} {kernel.dtype} and bias "
                             f"{bias.shape} {bias.dtype}")
        width = kernel.shape[1]
    log_std = arrays.pop("log_std", None)
    values = (arrays.pop("action/low"), arrays.pop("action/step")) \
        if "action/low" in arrays else None
    continuous = meta["action"]["kind"] == "continuous"
    if continuous != (log_std is not None or values is not None) or (
            log_std is not None and (values is not None or log_std.shape != (width,))):
        raise ValueError(f"a {meta['action']['kind']} action with log_std "
                         f"{None if log_std is None else log_std.shape}")
    if values is not None and (values[0].shape != values[1].shape or values[0].ndim != 1
                               or not values[0].shape[0] or width % values[0].shape[0]):
        raise ValueError(f"a discretized action of {width} logits with values "
                         f"{values[0].shape} and {values[1].shape}")
    observer = _observer(meta["observation"]["kind"], arrays)
    unknown = [k for k in arrays if not k.startswith("observer/")]
    if unknown:
        raise ValueError(f"unknown arrays {unknown}")
    return Policy(layers, activation, log_std, meta, observer, values)


def _numbers(value: Any, what: str, dtype: type = np.float32) -> np.ndarray:
    """``value`` as a finite array of ``dtype``, else :class:`DeployError`."""
    try:
        array = np.asarray(value, dtype)
    except (TypeError, ValueError):
        raise DeployError(f"{what} must be numbers, got {value!r:.80}") from None
    if not np.all(np.isfinite(array)):
        raise DeployError(f"{what} must be finite numbers, got {value!r:.80}")
    return array


def _observer(kind: str, arrays: dict[str, np.ndarray]
              ) -> GridObserver | ContinuousObserver | None:
    if not isinstance(kind, str):
        raise ValueError(f"observation kind {kind!r:.40}")
    if kind == "continuous":
        return ContinuousObserver(*(arrays[f"observer/{n}"] for n in
                                    ("walls", "avoid", "monitor", "beams", "ray_t")),
                                  factored=bool(arrays.get("observer/factored", False)),
                                  places=bool(arrays.get("observer/places", False)))
    if kind in ("factored", "onehot", "coords", "factored+onehot"):
        return GridObserver(arrays["observer/table"])
    return None  # an env of the user's own: its observations are the env's
