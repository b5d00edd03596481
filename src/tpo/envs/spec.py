"""Environments from what a user names, and from what a saved model records.

- :func:`make_env`: a JAX navigation env, a bundled map name or TOML path (a
  grid with random starts), or a Gymnasium env with vector rewards (see
  :func:`tpo.envs.gym_adapter.host_env`).
- :func:`from_spec`: the env of a spec written by an env's ``to_spec()``.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from tpo.envs.continuous import ContinuousNav
from tpo.envs.grid import GridNav
from tpo.envs.gym_adapter import EnvFactory, HostEnv, env_factory, host_env
from tpo.envs.maps import load_map, parse_map
from tpo.envs.random_tmdp import random_tmdp
from tpo.envs.tabular_env import TabularEnv
from tpo.errors import MapError, ModelError, TPOError
from tpo.schema import Number, check_table
from tpo.tabular import TabularTMDP

Env = GridNav | ContinuousNav | TabularEnv | HostEnv


def make_env(env: Env | str | Path | gym.Env | gym.vector.VectorEnv | EnvFactory,
             objectives: Sequence[str] | None, num_envs: int) -> Env:
    """The env a learner trains on. A Gymnasium env (``"PACKAGE:ENV_ID"``, a made
    env, a factory, a vector env) needs its reward components named in
    ``objectives``; a map becomes a grid with random starts."""
    if isinstance(env, Env):
        return env
    gym_like = isinstance(env, gym.Env | gym.vector.VectorEnv) or callable(env) or (
        isinstance(env, str) and ":" in env and not Path(env).exists())
    if gym_like:
        if objectives is None:
            raise TPOError("name the Gymnasium env's reward components in order: "
                           "objectives=[...]")
        return host_env(env, objectives, num_envs)
    try:
        navmap = load_map(env)
    except MapError as err:
        if Path(env).exists():
            raise
        raise MapError(f"{err}; a Gymnasium env is named PACKAGE:ENV_ID, e.g. "
                       "mo-gymnasium:deep-sea-treasure-v0") from None
    return GridNav(navmap, random_start=True)


#: The keys of every env kind's spec and their types (bool is not an int here).
SPEC_KEYS: dict[str, dict[str, type | tuple[type, ...]]] = {
    "grid": {"map": str, "slip": Number, "observation": str, "max_steps": int,
             "random_start": bool},
    "continuous": {"map": str, "action": str, "speed": Number, "noise": Number,
                   "n_beams": int, "max_range": Number, "max_steps": int,
                   "random_start": bool, "observation": str},
    "gym": {"id": str, "objectives": list},
    "random_tmdp": {"seed": int, "states": int, "actions": int, "objectives": int,
                    "dag": str, "stochastic": bool, "sparse": bool, "scale_spread": Number,
                    "slack": list, "observation": str, "features": int, "gamma": Number,
                    "max_steps": int, "random_start": bool},
    "tabular": {"successors": list, "probs": list, "rewards": list, "terminal": list,
                "objectives": list, "gamma": Number, "start": int,
                "observations": (list, type(None)), "max_steps": int, "random_start": bool},
}


def check_spec(spec: Any) -> None:
    """Raise :class:`TPOError` naming the first thing wrong with an env spec read from
    a file: its kind, a missing or unknown key, a value of the wrong type."""
    kind = spec.get("kind") if isinstance(spec, dict) else None
    if not isinstance(kind, str) or kind not in SPEC_KEYS:
        raise TPOError(f"unknown env kind {kind!r} (known: {', '.join(SPEC_KEYS)})")
    check_table(spec, SPEC_KEYS[kind], f"{kind} env spec", also=("kind",))
    if kind == "gym" and not all(isinstance(o, str) for o in spec["objectives"]):
        raise TPOError("gym env spec: objectives must be a list of names")


def from_spec(spec: dict[str, Any], *, evaluation: bool = False, num_envs: int = 1,
              trust_module: str | None = None) -> Env:
    """The env of ``spec`` (an env's ``to_spec()``, checked by :func:`check_spec`);
    ``evaluation`` drops a navigation env's random starts; a Gymnasium env gets ``num_envs``
    copies and is rebuilt without importing any module the spec names, unless it
    is ``trust_module`` (:func:`tpo.envs.gym_adapter.env_factory`)."""
    if isinstance(spec, dict) and spec.get("kind") == "continuous":
        # saved before continuous random starts, and before the factored observation
        spec = {"random_start": False, "observation": "coords", **spec}
    check_spec(spec)
    spec = dict(spec)
    kind = spec.pop("kind")
    if kind == "gym":
        return HostEnv(env_factory(spec["id"], trust_module=trust_module or False),
                       spec["objectives"], num_envs, env_id=spec["id"])
    if kind in ("random_tmdp", "tabular"):
        random_start = spec.pop("random_start") and not evaluation
        if kind == "random_tmdp":
            return random_tmdp(**spec).env(random_start)
        return _tabular_env(spec, random_start)
    navmap = parse_map(spec.pop("map"))
    if evaluation:
        spec["random_start"] = False
    if kind == "grid":
        return GridNav(navmap, **spec)
    if kind == "continuous":
        return ContinuousNav(navmap, **spec)


def _tabular_env(spec: dict[str, Any], random_start: bool) -> TabularEnv:
    """A :class:`TabularEnv` from its model's arrays (a ``tabular`` spec)."""
    try:
        model = TabularTMDP(np.asarray(spec["successors"]), np.asarray(spec["probs"], float),
                            np.asarray(spec["rewards"], float), tuple(spec["objectives"]),
                            spec["gamma"], spec["start"], np.asarray(spec["terminal"], bool))
        table = None if spec["observations"] is None else np.asarray(spec["observations"],
                                                                     np.float32)
    except (ValueError, TypeError) as err:
        raise ModelError(f"tabular env spec: {err}") from None
    return TabularEnv(model, table, spec["max_steps"], random_start)
