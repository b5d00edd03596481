"""Layer 5: experiments built on TPO — run directories and the paper's reproduction."""

from tpo.experiments.runs import RunError, RunSpec, create_run, train_run

__all__ = ["RunError", "RunSpec", "create_run", "train_run"]
