"""The project's error types.

Every mistake a user can make (a malformed DAG, a bad model, an infeasible
problem) raises a subclass of :class:`TPOError` whose message names the
problem in one line. The command line prints that line and exits non-zero.
"""

from __future__ import annotations


class TPOError(ValueError):
    """Base class of every error raised for bad input to tpo."""


class GraphError(TPOError):
    """A malformed objective DAG, spec string or slack."""


class ModelError(TPOError):
    """A malformed finite TMDP (shapes, probabilities, rewards, gamma)."""


class MapError(TPOError):
    """A malformed navigation map."""


class DamagedModel(TPOError):
    """A saved model (or checkpoint) whose files cannot be read or fail their checks."""


class InfeasibleError(TPOError):
    """LAR found states where an objective has no admissible action.

    Attributes:
        objective: name of the first objective whose action set is empty.
        states: indices of the states where it is empty.
    """

    def __init__(self, objective: str, states: list[int]) -> None:
        shown = ", ".join(map(str, states[:10])) + (", ..." if len(states) > 10 else "")
        super().__init__(
            f"infeasible: objective '{objective}' has no action within the slack of all its "
            f"parents at {len(states)} state(s) [{shown}]; raise the slack or relax the problem"
        )
        self.objective = objective
        self.states = states
