"""Layer 4: TPO (paper Algorithm 1) and plain PPO, end to end in JAX. Names load on
first use (``tpo.algo.config`` alone loads no JAX)."""

from typing import TYPE_CHECKING

from tpo.lazy import lazy_names

if TYPE_CHECKING:  # what type checkers and IDEs see
    from tpo.algo.config import ConfigError, TPOConfig
    from tpo.algo.guard import NonFiniteError
    from tpo.algo.phases import Problem
    from tpo.algo.tpo import TPO
    from tpo.algo.train import Trainer, TrainState

_LAZY = {"TPO": "tpo.algo.tpo", "ConfigError": "tpo.algo.config",
         "TPOConfig": "tpo.algo.config", "NonFiniteError": "tpo.algo.guard",
         "Problem": "tpo.algo.phases", "Trainer": "tpo.algo.train",
         "TrainState": "tpo.algo.train"}

__all__ = ["TPO", "ConfigError", "NonFiniteError", "Problem", "TPOConfig", "TrainState",
           "Trainer"]

__getattr__, __dir__ = lazy_names(__name__, _LAZY, globals())
