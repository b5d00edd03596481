"""What the continuous navigation robot senses, written once for NumPy and JAX.

Every function takes the array module ``xp`` (``numpy`` or ``jax.numpy``), so the
JAX env (:class:`tpo.envs.continuous.ContinuousNav`) and the NumPy-only runner of
exported policies (:mod:`tpo.deploy`) compute the same observation from a
position. This module imports NumPy alone.
"""

from __future__ import annotations

from typing import Any

import numpy as np

RAY_STEP = 0.2  # distance between the points sampled along a sensor beam, in cells


def ray_distances(max_range: float) -> np.ndarray:
    """The distances sampled along a beam, ``float32 [M]``: ``RAY_STEP`` to ``max_range``."""
    return np.arange(RAY_STEP, max_range + 1e-6, RAY_STEP, dtype=np.float32)


def pad_walls(walls: np.ndarray) -> np.ndarray:
    """``walls [H, W]`` (bool) inside a border of wall cells, ``[H + 2, W + 2]``: what
    :func:`blocked` reads."""
    return np.pad(np.asarray(walls, bool), 1, constant_values=True)


def blocked(points: Any, padded: Any, xp: Any = np) -> Any:
    """Whether each point ``[..., 2]`` (row, col) lies off the map or in a wall cell,
    read from the map's :func:`pad_walls` ``padded`` in one flat gather (a point off
    the map is clipped onto the border, a wall)."""
    hp, wp = padded.shape
    cell = xp.clip(xp.floor(points) + 1, 0, xp.array([hp - 1, wp - 1], xp.float32))
    return _read(padded, cell.astype(xp.int32), xp)


def _read(padded: Any, cell: Any, xp: Any) -> Any:
    """``padded`` at the integer cells ``[..., 2]`` in one flat gather (the flat
    index clipped onto the table)."""
    return xp.take(padded.reshape(-1), cell[..., 0] * padded.shape[1] + cell[..., 1],
                   mode="clip")


def range_readings(pos: Any, padded: Any, beams: Any, ray_t: Any, xp: Any = np) -> Any:
    """A range sensor at ``pos [2]``, a point on the map whose :func:`pad_walls` is
    ``padded``: along each beam ``[K, 2]`` the distance to the first blocked point
    sampled at ``ray_t [M]`` (less half a step), or ``ray_t[-1]``: ``[K]``.

    :func:`blocked` clips every point onto the border; here only the flat index is
    clipped, which is exact: samples are less than a cell apart, so every one up to
    the first blocked lies on the padded map (the border is a wall), and what is
    read past it only adds later hits, which the minimum ignores (a third of the
    time of clipping each point and taking the first hit by ``argmax``:
    docs/notes/tpo-learning.md, session 34)."""
    points = pos + beams[:, None, :] * ray_t[None, :, None]  # [K, M, 2]
    hit = _read(padded, xp.floor(points).astype(xp.int32) + 1, xp)
    return xp.min(xp.where(hit, ray_t - RAY_STEP / 2, ray_t[-1]), axis=1)


def observation(pos: Any, distances: Any, avoid: Any, monitor: Any, max_range: Any,
                xp: Any = np, factored: bool = False, places: bool = False) -> Any:
    """The observation ``[4 + K]``: ``pos`` scaled to ``[0, 1]`` by the map's shape,
    ``distances [K]`` divided by ``max_range``, and whether ``pos`` is in an avoid and
    in a monitor region; ``factored`` appends :func:`cell_features` (``H + W``
    numbers), then ``places`` :func:`place_features` (``H * W``)."""
    h, w = avoid.shape
    cell = xp.floor(pos).astype(xp.int32)
    parts = [pos / xp.array([h, w], xp.float32),
             distances / max_range,
             xp.stack([avoid[cell[0], cell[1]], monitor[cell[0], cell[1]]]).astype(xp.float32)]
    if factored or places:
        tents = cell_features(pos, (h, w), xp)
        if factored:
            parts.append(tents)
        if places:
            parts.append(_products(tents, h))
    return xp.concatenate(parts)


def cell_features(pos: Any, shape: tuple[int, int], xp: Any = np) -> Any:
    """The continuous counterpart of the grid's row and column one-hots, ``[H + W]``:
    a tent of width one cell about every row's and column's centre,
    ``max(0, 1 - |pos - (i + 1/2)|)``. At a cell's centre they are its row's and
    column's one-hots; between two centres they share the weight linearly, so
    they are continuous in the position. Sharp local features an MLP combines
    into places (the grid's factored observation learns TPO's critics where
    coordinates alone do not: README, "Observations")."""
    h, w = shape
    row = xp.maximum(0.0, 1.0 - xp.abs(pos[0] - (xp.arange(h, dtype=xp.float32) + 0.5)))
    col = xp.maximum(0.0, 1.0 - xp.abs(pos[1] - (xp.arange(w, dtype=xp.float32) + 0.5)))
    return xp.concatenate([row, col]).astype(xp.float32)


def place_features(pos: Any, shape: tuple[int, int], xp: Any = np) -> Any:
    """A tent about every cell's centre, ``[H * W]`` (row-major): the product of the
    cell's row and column tents of :func:`cell_features`, so at a cell's centre its
    one-hot and in between the bilinear weights of the (up to 4) nearest centres.
    The row and column tents alone let a network value a place by its column, as a
    corridor below a door (docs/notes/tpo-learning.md, session 39); these tell
    places apart."""
    return _products(cell_features(pos, shape, xp), shape[0])


def _products(tents: Any, h: int) -> Any:
    """Every cell's row tent times its column tent, row-major, from
    :func:`cell_features` ``tents`` of a map ``h`` rows high."""
    return (tents[:h, None] * tents[None, h:]).reshape(-1)
