"""Run directories: what ``tpo train`` writes and ``tpo eval`` / ``tpo train --resume``
read::

    RUN/
      config.toml           the resolved settings (run fields + every TPOConfig field);
                            ``tpo train --config RUN/config.toml`` trains the same run
      metrics.csv           one row per update
      tb/                   TensorBoard event files with the same scalars
      checkpoints/update-N/ the whole training state after update N (a saved model)
      model/                the final model (``TPO.load``)
      eval.json             ``mc``, ``exact`` and ``lar`` of :meth:`TPO.evaluate`

Every file is written whole and renamed into place (or, for the metrics,
truncated back to the last checkpoint on resume), so a kill never leaves a
file that a later run trusts half-written.
"""

from __future__ import annotations

import json
import math
import shutil
import tomllib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from tpo.algo import TPO, TPOConfig, Trainer
from tpo.atomic import write_atomic
from tpo.envs import load_map
from tpo.envs.grid import GridNav
from tpo.errors import TPOError

RUN_DEFAULTS: dict[str, Any] = {"map": "home", "dag": "M>A>G", "slack": [0.0], "seed": 0,
                                "steps": 1_000_000, "slip": 0.0, "observation": "factored",
                                "env": "", "objectives": []}
METRICS = ("episode_return", "episode_length", "penalty", "violation_rate", "policy_loss",
           "value_loss", "entropy", "approx_kl", "lr")
CHECKPOINTS = 10  # per run, at chunk boundaries


class RunError(TPOError):
    """A run directory that cannot be created, read or resumed."""


@dataclass(frozen=True)
class RunSpec:
    """What one ``tpo train`` run trains: the problem fields and the hyperparameters."""

    map: str
    dag: str
    slack: tuple[float, ...]
    seed: int
    steps: int
    slip: float
    observation: str
    config: TPOConfig
    env: str = ""  # a Gymnasium env "PACKAGE:ENV_ID" instead of a map
    objectives: tuple[str, ...] = ()  # its reward components, in order

    @classmethod
    def from_settings(cls, settings: dict[str, Any]) -> RunSpec:
        """Run fields (defaults in :data:`RUN_DEFAULTS`) plus any TPOConfig field."""
        settings = dict(settings)
        run = {k: settings.pop(k, v) for k, v in RUN_DEFAULTS.items()}
        slack = run["slack"]
        slack = [slack] if isinstance(slack, int | float) else slack
        try:
            slack = tuple(float(v) for v in slack)
        except (TypeError, ValueError):
            raise RunError(f"slack must be a number or a list of numbers, got {slack!r}"
                           ) from None
        for name in ("seed", "steps"):
            if isinstance(run[name], bool) or not isinstance(run[name], int):
                raise RunError(f"{name} must be an integer, got {run[name]!r}")
        objectives = run["objectives"]
        if isinstance(objectives, str):
            objectives = [o.strip() for o in objectives.split(",") if o.strip()]
        if run["env"] and not objectives:
            raise RunError(f"name the reward components of env '{run['env']}' in order: "
                           "--objectives a,b,...")
        return cls(map=str(run["map"]), dag=str(run["dag"]), slack=slack, seed=run["seed"],
                   steps=run["steps"], slip=float(run["slip"]),
                   observation=str(run["observation"]), config=TPOConfig.from_dict(settings),
                   env=str(run["env"]), objectives=tuple(objectives))

    @classmethod
    def from_toml(cls, path: str | Path) -> RunSpec:
        try:
            return cls.from_settings(tomllib.loads(Path(path).read_text()))
        except (OSError, tomllib.TOMLDecodeError) as err:
            raise RunError(f"cannot read {path}: {err}") from None

    def to_toml(self) -> str:
        problem = ({"env": self.env, "objectives": list(self.objectives)} if self.env else
                   {"map": self.map, "slip": self.slip, "observation": self.observation})
        fields = {**problem, "dag": self.dag, "slack": list(self.slack), "seed": self.seed,
                  "steps": self.steps, **self.config.to_dict()}
        return "".join(f"{k} = {_toml_value(v)}\n" for k, v in fields.items())

    def check(self) -> None:
        """Raise on anything training would refuse (map, DAG, slack, env, budget),
        before a run directory is made."""
        model = self.model()
        Trainer(model.env, model.graph, self.config, self.steps)

    def model(self) -> TPO:
        """A fresh (untrained) model of this run; on a map, training starts from
        random starts."""
        if self.env:
            return TPO(self.env, self.dag, slack=list(self.slack), config=self.config,
                       seed=self.seed, objectives=self.objectives)
        env = GridNav(load_map(self.map), slip=self.slip, observation=self.observation,
                      random_start=True)
        return TPO(env, self.dag, slack=list(self.slack), config=self.config, seed=self.seed)


def _toml_value(value: object) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    return repr(value)


class MetricsLog:
    """Per-update metrics to ``metrics.csv`` and TensorBoard (``tb/``).

    The CSV is appended chunk by chunk; :meth:`open` first cuts it back to the
    rows up to ``last_update`` (those of the checkpoint a resume starts from), so
    rows are never doubled or half-written.
    """

    def __init__(self, run_dir: Path, objectives: tuple[str, ...], phases: tuple[str, ...],
                 batch_size: int, last_update: int = 0) -> None:
        from tensorboardX import SummaryWriter

        self.objectives, self.phases, self.batch_size = objectives, phases, batch_size
        self.header = ["update", "timesteps", "phase",
                       *[f"return_{n}" for n in objectives], *METRICS[1:]]
        path = run_dir / "metrics.csv"
        kept = [",".join(self.header)]
        if last_update and path.exists():
            kept += [row for row in path.read_text().splitlines()[1:]
                     if row.count(",") == len(self.header) - 1
                     and int(row.split(",")[0]) <= last_update]
        write_atomic(path, "\n".join(kept) + "\n")
        self.csv = open(path, "a")  # noqa: SIM115 - closed in close()
        self.tb = SummaryWriter(str(run_dir / "tb"), purge_step=last_update * batch_size
                                if last_update else None)

    def write(self, metrics: dict[str, np.ndarray], updates_done: int) -> None:
        n = len(metrics["phase"])
        for i in range(n):
            update = updates_done - n + i + 1
            step = update * self.batch_size
            phase = int(metrics["phase"][i])
            returns = metrics["episode_return"][i]
            values = [float(metrics[m][i]) for m in METRICS[1:]]
            self.csv.write(",".join([str(update), str(step), self.phases[phase],
                                     *[f"{r:.6g}" for r in returns],
                                     *[f"{v:.6g}" for v in values]]) + "\n")
            self.tb.add_scalar("phase", phase, step)
            for name, r in zip(self.objectives, returns, strict=True):
                self.tb.add_scalar(f"return/{name}", float(r), step)
            for name, v in zip(METRICS[1:], values, strict=True):
                self.tb.add_scalar(f"train/{name}", v, step)
        self.csv.flush()
        self.tb.flush()

    def close(self) -> None:
        self.csv.close()
        self.tb.close()


def checkpoints(run_dir: Path) -> list[Path]:
    """The run's checkpoints, oldest first."""
    root = run_dir / "checkpoints"
    found = [p for p in root.glob("update-*") if p.is_dir()] if root.exists() else []
    return sorted(found, key=lambda p: int(p.name.split("-")[1]))


def create_run(out: str | Path, spec: RunSpec, force: bool = False) -> Path:
    """Make the run directory with its ``config.toml``; an existing one is kept
    unless ``force``."""
    out = Path(out)
    if out.exists() and any(out.iterdir()) and not force:
        raise RunError(f"run directory {out} exists; pass --force to replace it "
                       "or --resume to continue it")
    if out.exists() and force:
        shutil.rmtree(out)
    out.mkdir(parents=True, exist_ok=True)
    write_atomic(out / "config.toml", spec.to_toml())
    return out


Progress = Callable[[TPO, dict[str, np.ndarray], int], None]


def train_run(run_dir: str | Path, episodes: int = 100, progress: Progress | None = None,
              chunk_updates: int = 16) -> dict[str, Any]:
    """Train the run in ``run_dir`` to its end, or resume it from its last checkpoint,
    checkpointing about :data:`CHECKPOINTS` times; then save the model and write
    ``eval.json``."""
    run_dir = Path(run_dir)
    spec = RunSpec.from_toml(run_dir / "config.toml")
    saved = checkpoints(run_dir)
    model = TPO.load(saved[-1]) if saved else spec.model()
    log = MetricsLog(run_dir, model.env.objectives, model.graph.order, spec.config.batch_size,
                     int(model.state.update) if saved else 0)

    def on_chunk(metrics: dict[str, np.ndarray], done: int) -> None:
        log.write(metrics, done)
        total = model.trainer.num_updates
        every = chunk_updates * max(1, math.ceil(total / CHECKPOINTS / chunk_updates))
        if done % every == 0 or done == total:
            model.save(run_dir / "checkpoints" / f"update-{done:06d}", overwrite=True)
        if progress is not None:
            progress(model, metrics, done)

    try:
        if saved:
            model.resume(on_chunk, chunk_updates)
        else:
            model.learn(spec.steps, on_chunk, chunk_updates)
    finally:
        log.close()
    model.save(run_dir / "model", overwrite=True)
    result = model.evaluate(episodes=episodes)
    write_atomic(run_dir / "eval.json", json.dumps(result, indent=2))
    return result
