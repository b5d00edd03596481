"""Layer 5: experiments built on TPO — run directories, sweeps and the paper's
reproduction. Names load on first use, so the command line starts without JAX."""

from typing import TYPE_CHECKING

from tpo.lazy import lazy_names

if TYPE_CHECKING:  # what type checkers and IDEs see
    from tpo.experiments.runs import create_run, train_run
    from tpo.experiments.runspec import RunError, RunSpec

_LAZY = {"RunError": "tpo.experiments.runspec", "RunSpec": "tpo.experiments.runspec",
         "create_run": "tpo.experiments.runs", "train_run": "tpo.experiments.runs"}

__all__ = ["RunError", "RunSpec", "create_run", "train_run"]

__getattr__, __dir__ = lazy_names(__name__, _LAZY, globals())
