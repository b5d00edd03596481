"""tpo: reinforcement learning with prioritised, slack-tolerant objectives.

Layers (a lower one never imports a higher one; docs/design.md §4)::

    tpo.errors, tpo.atomic  error types; files written whole or not at all
    tpo.graph               objectives, DAG, slack
    tpo.tabular             exact solvers (LAR, Lagrangian Bellman, evaluation, gradient)
    tpo.envs                the navigation domain (maps, exact models, JAX envs) and
                            Gymnasium adapters
    tpo.algo                TPO and plain PPO in JAX (the ``TPO`` model)
    tpo.experiments         run directories, sweeps, the paper's reproduction
    tpo.cli                 the command line
"""

from tpo.errors import GraphError, InfeasibleError, ModelError, TPOError
from tpo.lazy import lazy_names

__version__ = "0.2.0"
__all__ = ["GraphError", "InfeasibleError", "ModelError", "ObjectiveGraph", "TPOError"]

# Loaded on first use, so that tpo.deploy imports NumPy alone.
__getattr__, __dir__ = lazy_names(__name__, {"ObjectiveGraph": "tpo.graph"}, globals())
