"""Layer 3: the multi-objective robot navigation domain."""

from tpo.envs.grid_model import ACTIONS, GridModel, grid_model
from tpo.envs.maps import OBJECTIVES, NavMap, bundled_maps, load_map, parse_map

__all__ = ["ACTIONS", "OBJECTIVES", "GridModel", "NavMap", "bundled_maps", "grid_model",
           "load_map", "parse_map"]
