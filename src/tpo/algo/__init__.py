"""Layer 4: TPO (paper Algorithm 1) and plain PPO, end to end in JAX."""

from tpo.algo.agent import TPO
from tpo.algo.config import ConfigError, TPOConfig
from tpo.algo.train import Problem, Trainer, TrainState

__all__ = ["TPO", "ConfigError", "Problem", "TPOConfig", "TrainState", "Trainer"]
