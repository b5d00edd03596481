"""Layer 2: exact tabular solvers in NumPy float64, the ground truth for everything learned."""

from tpo.tabular.bellman import ATOL, VI_TOL
from tpo.tabular.evaluation import (
    discounted_visitation,
    evaluate_policy,
    policy_gradient,
    q_values,
    softmax,
)
from tpo.tabular.judge import VERDICTS, Judge, Verdict, floors, tolerance
from tpo.tabular.lagrangian import LagrangianSolution, multiplier_bound, solve_lagrangian
from tpo.tabular.lar import LARSolution, Solution, solve_lar
from tpo.tabular.model import TabularTMDP

__all__ = [
    "ATOL",
    "VERDICTS",
    "VI_TOL",
    "Judge",
    "LARSolution",
    "LagrangianSolution",
    "Solution",
    "TabularTMDP",
    "Verdict",
    "discounted_visitation",
    "evaluate_policy",
    "floors",
    "multiplier_bound",
    "policy_gradient",
    "q_values",
    "softmax",
    "solve_lagrangian",
    "solve_lar",
    "tolerance",
]
