"""Layer 3: the multi-objective robot navigation domain, and finite TMDPs as envs.

NumPy parts (maps, exact grid model, rendering) load eagerly; the JAX
environments (:class:`GridNav`, :class:`ContinuousNav`, :class:`TabularEnv` over
any finite TMDP) and their Gymnasium front ends load on first use, as does the
generator of random TMDPs (:mod:`tpo.envs.random_tmdp`). Importing this package registers
the Gymnasium ids ``tpo/GridNav-home-v0`` etc. and ``tpo/RandomTMDP-v0``.
"""

from tpo.envs.grid_model import ACTIONS, GridModel, grid_model
from tpo.envs.maps import OBJECTIVES, NavMap, bundled_maps, load_map, parse_map
from tpo.envs.registration import register_envs
from tpo.lazy import lazy_names

_LAZY = {
    "GridNav": "tpo.envs.grid",
    "ContinuousNav": "tpo.envs.continuous",
    "GridNavEnv": "tpo.envs.gym_envs",
    "ContinuousNavEnv": "tpo.envs.gym_envs",
    "make_env": "tpo.envs.spec",
    "from_spec": "tpo.envs.spec",
    "TabularEnv": "tpo.envs.tabular_env",
    "TabularGymEnv": "tpo.envs.tabular_env",
    "RandomTMDP": "tpo.envs.random_tmdp",
}

__all__ = ["ACTIONS", "OBJECTIVES", "ContinuousNav", "ContinuousNavEnv", "GridModel",
           "GridNav", "GridNavEnv", "NavMap", "RandomTMDP", "TabularEnv", "TabularGymEnv",
           "bundled_maps", "from_spec", "grid_model", "load_map", "make_env", "parse_map",
           "register_envs"]

register_envs()

__getattr__, __dir__ = lazy_names(__name__, _LAZY, globals())
