"""Layer 5: experiments built on TPO — run directories, sweeps and the paper's
reproduction. Names load on first use, so the command line starts without JAX."""

from importlib import import_module
from typing import Any

_LAZY = {"RunError": "tpo.experiments.runspec", "RunSpec": "tpo.experiments.runspec",
         "create_run": "tpo.experiments.runs", "train_run": "tpo.experiments.runs"}

__all__ = sorted(_LAZY)


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'tpo.experiments' has no attribute '{name}'")
