"""Layer 3: the multi-objective robot navigation domain.

NumPy parts (maps, exact grid model, rendering) load eagerly; the JAX
environments (:class:`GridNav`, :class:`ContinuousNav`) and their Gymnasium
front ends (:class:`GridNavEnv`, :class:`ContinuousNavEnv`) load on first use.
Importing this package registers the Gymnasium ids ``tpo/GridNav-home-v0`` etc.
"""

from importlib import import_module
from typing import Any

from tpo.envs.grid_model import ACTIONS, GridModel, grid_model
from tpo.envs.maps import OBJECTIVES, NavMap, bundled_maps, load_map, parse_map
from tpo.envs.registration import register_envs

_LAZY = {
    "GridNav": "tpo.envs.grid",
    "ContinuousNav": "tpo.envs.continuous",
    "GridNavEnv": "tpo.envs.gym_envs",
    "ContinuousNavEnv": "tpo.envs.gym_envs",
    "make_env": "tpo.envs.spec",
    "from_spec": "tpo.envs.spec",
}

__all__ = ["ACTIONS", "OBJECTIVES", "ContinuousNav", "ContinuousNavEnv", "GridModel",
           "GridNav", "GridNavEnv", "NavMap", "bundled_maps", "from_spec", "grid_model",
           "load_map", "make_env", "parse_map", "register_envs"]

register_envs()


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'tpo.envs' has no attribute '{name}'")


def __dir__() -> list[str]:
    return sorted([*globals(), *_LAZY])
