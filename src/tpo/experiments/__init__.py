"""Layer 5: experiments built on TPO — run directories, sweeps and the paper's
reproduction. Names load on first use, so the command line starts without JAX."""

from importlib import import_module
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # what type checkers and IDEs see
    from tpo.experiments.runs import create_run, train_run
    from tpo.experiments.runspec import RunError, RunSpec

_LAZY = {"RunError": "tpo.experiments.runspec", "RunSpec": "tpo.experiments.runspec",
         "create_run": "tpo.experiments.runs", "train_run": "tpo.experiments.runs"}

__all__ = ["RunError", "RunSpec", "create_run", "train_run"]


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'tpo.experiments' has no attribute '{name}'")


def __dir__() -> list[str]:
    return sorted([*globals(), *_LAZY])
