"""Occupancy-grid maps of the navigation domain (paper §V-A, docs/design.md §3).

A map is a TOML file::

    name = "example"
    max_steps = 200
    grid = \"\"\"
    ##########
    #S...#...#
    #....#.G.#
    ##########
    \"\"\"
    avoid = [[1, 2, 2, 3]]     # inclusive rectangles [row0, col0, row1, col1]
    monitor = [[2, 6, 2, 8]]

``#`` is a wall, ``.`` free, ``S`` the start and ``G`` the goal (both free).
Instead of ``S``/``G`` the start and goal may be given as ``start = [row, col]``
and ``goal = [row, col]``. Everything outside the grid counts as wall.
"""

from __future__ import annotations

import hashlib
import tomllib
from collections import deque
from dataclasses import dataclass
from functools import cached_property
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import tomli_w

from tpo.errors import MapError

OBJECTIVES = ("goal", "avoid", "monitor")
CELLS = {"#": True, ".": False, "S": False, "G": False}
MAX_STEPS = 2**31 - 1  # the env's step counter is an int32
KEYS = {"name", "max_steps", "grid", "avoid", "monitor", "start", "goal", "description"}


@dataclass(frozen=True, eq=False)
class NavMap:
    """A validated map.

    Attributes:
        name: the map's name.
        walls: bool ``[H, W]``, True on walls.
        start, goal: ``(row, col)`` free cells; the goal is reachable from the start.
        avoid, monitor: inclusive rectangles ``(row0, col0, row1, col1)``.
        max_steps: the episode's time limit (truncation).
        description: free text.
    """

    name: str
    walls: np.ndarray
    start: tuple[int, int]
    goal: tuple[int, int]
    avoid: tuple[tuple[int, int, int, int], ...]
    monitor: tuple[tuple[int, int, int, int], ...]
    max_steps: int
    description: str = ""

    @property
    def shape(self) -> tuple[int, int]:
        return self.walls.shape

    @cached_property
    def avoid_mask(self) -> np.ndarray:
        """bool ``[H, W]``: cells inside an avoid rectangle."""
        return _rect_mask(self.shape, self.avoid)

    @cached_property
    def monitor_mask(self) -> np.ndarray:
        """bool ``[H, W]``: cells inside a monitor rectangle."""
        return _rect_mask(self.shape, self.monitor)

    @property
    def n_free(self) -> int:
        return int((~self.walls).sum())

    def start_cells(self, random_start: bool) -> np.ndarray:
        """int ``[N, 2]``: the cells an episode may start in: every non-goal free cell
        with ``random_start`` (exploring starts), else the map's start."""
        if not random_start:
            return np.array([self.start])
        free = ~self.walls
        free[self.goal] = False
        return np.argwhere(free)

    def sha256(self) -> str:
        """The SHA-256 of :meth:`to_toml`: what the map is, whatever its file."""
        return hashlib.sha256(self.to_toml().encode()).hexdigest()

    def to_toml(self) -> str:
        """TOML text that :func:`parse_map` reads back to the same map."""
        rows = ["".join("#" if w else "." for w in row) for row in self.walls]
        for ch, (r, c) in (("S", self.start), ("G", self.goal)):
            rows[r] = rows[r][:c] + ch + rows[r][c + 1:]
        return tomli_w.dumps({"name": self.name, "max_steps": self.max_steps,
                              "grid": "\n".join(rows) + "\n",
                              "avoid": [list(map(int, r)) for r in self.avoid],
                              "monitor": [list(map(int, r)) for r in self.monitor]},
                             multiline_strings=True)


def bundled_maps() -> list[str]:
    """Names of the maps shipped with tpo."""
    folder = resources.files("tpo.envs") / "maps"
    return sorted(p.name.removesuffix(".toml") for p in folder.iterdir()
                  if p.name.endswith(".toml"))


def check_max_steps(steps: Any) -> int:
    """``steps`` if it is a valid episode limit, else :class:`MapError`."""
    if isinstance(steps, bool) or not isinstance(steps, int) or not 1 <= steps <= MAX_STEPS:
        raise MapError(f"max_steps must be an integer from 1 to {MAX_STEPS} (an int32 step "
                       f"counter), got {steps!r}")
    return steps


def load_map(name_or_path: str | Path) -> NavMap:
    """A bundled map by name, or a map from a TOML file path."""
    text: str
    source = str(name_or_path)
    if str(name_or_path) in bundled_maps():
        text = (resources.files("tpo.envs") / "maps" / f"{name_or_path}.toml").read_text()
    else:
        path = Path(name_or_path)
        if path.exists() and not path.is_file():
            raise MapError(f"map {path} is not a regular file")
        if not path.is_file():
            raise MapError(f"no bundled map or file named '{name_or_path}' "
                           f"(bundled: {', '.join(bundled_maps())})")
        try:
            text = path.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as err:
            raise MapError(f"cannot read map {path}: {err}") from None
    return parse_map(text, source)


def parse_map(text: str, source: str = "<map>") -> NavMap:
    """Parse and validate a map from TOML text; ``source`` names it in errors."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise MapError(f"{source}: bad TOML: {err}") from None
    return map_from_dict(data, source)


def map_from_dict(data: dict[str, Any], source: str = "<map>") -> NavMap:
    """Validate a map given as a dict with the TOML keys."""
    def fail(msg: str) -> MapError:
        return MapError(f"{source}: {msg}")

    unknown = set(data) - KEYS
    if unknown:
        raise fail(f"unknown key(s) {', '.join(sorted(unknown))}; "
                   f"allowed: {', '.join(sorted(KEYS))}")
    if "grid" not in data or not isinstance(data["grid"], str):
        raise fail("needs a 'grid' string")
    rows = [r.strip() for r in data["grid"].strip("\n").splitlines()]
    rows = [r for r in rows if r]
    if not rows:
        raise fail("empty grid")
    width = len(rows[0])
    for i, row in enumerate(rows):
        if len(row) != width:
            raise fail(f"ragged grid: row {i} has {len(row)} cells, row 0 has {width}")
        bad = sorted(set(row) - set(CELLS))
        if bad:
            raise fail(f"unknown character(s) {''.join(bad)!r} in grid row {i}; "
                       "use # . S G")
    walls = np.array([[CELLS[ch] for ch in row] for row in rows])
    start = _marked_cell(rows, "S", data.get("start"), "start", fail)
    goal = _marked_cell(rows, "G", data.get("goal"), "goal", fail)
    for what, (r, c) in (("start", start), ("goal", goal)):
        if not (0 <= r < walls.shape[0] and 0 <= c < walls.shape[1]):
            raise fail(f"{what} {[r, c]} is outside the {walls.shape[0]}x{walls.shape[1]} grid")
        if walls[r, c]:
            raise fail(f"{what} {[r, c]} is on a wall")
    if start == goal:
        raise fail("start and goal are the same cell")
    name = data.get("name", Path(source).stem)
    if not isinstance(name, str) or not name:
        raise fail("'name' must be a non-empty string")
    max_steps = data.get("max_steps", 200)
    try:
        check_max_steps(max_steps)
    except MapError as err:
        raise fail(str(err)) from None
    avoid = _rects(data.get("avoid", []), "avoid", walls.shape, fail)
    monitor = _rects(data.get("monitor", []), "monitor", walls.shape, fail)
    if not _reachable(walls, start, goal):
        raise fail(f"goal {list(goal)} is unreachable from start {list(start)}")
    return NavMap(name, walls, start, goal, avoid, monitor, max_steps,
                  str(data.get("description", "")))


def _marked_cell(rows: list[str], ch: str, given: Any, what: str, fail) -> tuple[int, int]:
    marks = [(r, c) for r, row in enumerate(rows) for c, x in enumerate(row) if x == ch]
    if given is not None:
        if marks:
            raise fail(f"{what} given both as '{ch}' in the grid and as a '{what}' key")
        if (not isinstance(given, list) or len(given) != 2
                or not all(isinstance(v, int) and not isinstance(v, bool) for v in given)):
            raise fail(f"'{what}' must be [row, col] integers, got {given!r}")
        return int(given[0]), int(given[1])
    if len(marks) != 1:
        found = "no" if not marks else f"{len(marks)}"
        raise fail(f"the grid needs exactly one '{ch}' ({what}), found {found}")
    return marks[0]


def _rects(value: Any, what: str, shape: tuple[int, int], fail) -> tuple:
    if not isinstance(value, list):
        raise fail(f"'{what}' must be a list of [row0, col0, row1, col1] rectangles")
    out = []
    for rect in value:
        if (not isinstance(rect, list) or len(rect) != 4
                or not all(isinstance(v, int) and not isinstance(v, bool) for v in rect)):
            raise fail(f"{what} rectangle {rect!r} must be 4 integers [row0, col0, row1, col1]")
        r0, c0, r1, c1 = rect
        if r0 > r1 or c0 > c1:
            raise fail(f"{what} rectangle {rect} is inverted (needs row0 <= row1, col0 <= col1)")
        if r0 < 0 or c0 < 0 or r1 >= shape[0] or c1 >= shape[1]:
            raise fail(f"{what} rectangle {rect} lies outside the {shape[0]}x{shape[1]} grid")
        out.append((r0, c0, r1, c1))
    return tuple(out)


def _rect_mask(shape: tuple[int, int], rects) -> np.ndarray:
    mask = np.zeros(shape, bool)
    for r0, c0, r1, c1 in rects:
        mask[r0:r1 + 1, c0:c1 + 1] = True
    return mask


def _reachable(walls: np.ndarray, start: tuple[int, int], goal: tuple[int, int]) -> bool:
    seen = {start}
    queue = deque([start])
    while queue:
        r, c = queue.popleft()
        if (r, c) == goal:
            return True
        for dr, dc in ((-1, 0), (1, 0), (0, -1), (0, 1)):
            n = (r + dr, c + dc)
            if (0 <= n[0] < walls.shape[0] and 0 <= n[1] < walls.shape[1]
                    and not walls[n] and n not in seen):
                seen.add(n)
                queue.append(n)
    return False
