"""tpo: reinforcement learning with prioritised, slack-tolerant objectives.

Layers (a lower one never imports a higher one)::

    tpo.graph    objectives, DAG, slack
    tpo.tabular  exact solvers (LAR, Lagrangian Bellman, evaluation, gradient)
    tpo.envs     the navigation domain (maps, exact models)
    tpo.cli      the command line
"""

from tpo.errors import GraphError, InfeasibleError, ModelError, TPOError
from tpo.graph import ObjectiveGraph

__version__ = "0.1.0"
__all__ = ["GraphError", "InfeasibleError", "ModelError", "ObjectiveGraph", "TPOError"]
