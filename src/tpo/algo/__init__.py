"""Layer 4: TPO (paper Algorithm 1) and plain PPO, end to end in JAX. Names load on
first use (``tpo.algo.config`` alone loads no JAX)."""

from importlib import import_module
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # what type checkers and IDEs see
    from tpo.algo.config import ConfigError, TPOConfig
    from tpo.algo.guard import NonFiniteError
    from tpo.algo.tpo import TPO
    from tpo.algo.train import Problem, Trainer, TrainState

_LAZY = {"TPO": "tpo.algo.tpo", "ConfigError": "tpo.algo.config",
         "TPOConfig": "tpo.algo.config", "NonFiniteError": "tpo.algo.guard",
         "Problem": "tpo.algo.train", "Trainer": "tpo.algo.train",
         "TrainState": "tpo.algo.train"}

__all__ = ["TPO", "ConfigError", "NonFiniteError", "Problem", "TPOConfig", "TrainState",
           "Trainer"]


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'tpo.algo' has no attribute '{name}'")


def __dir__() -> list[str]:
    return sorted([*globals(), *_LAZY])
