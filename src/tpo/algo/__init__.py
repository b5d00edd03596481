"""Layer 4: TPO (paper Algorithm 1) and plain PPO, end to end in JAX. Names load on
first use (``tpo.algo.config`` alone loads no JAX)."""

from importlib import import_module
from typing import Any

_LAZY = {"TPO": "tpo.algo.tpo", "ConfigError": "tpo.algo.config",
         "TPOConfig": "tpo.algo.config", "NonFiniteError": "tpo.algo.guard",
         "Problem": "tpo.algo.train", "Trainer": "tpo.algo.train",
         "TrainState": "tpo.algo.train"}

__all__ = sorted(_LAZY)


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'tpo.algo' has no attribute '{name}'")
