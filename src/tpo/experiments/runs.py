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
      .tpo.run              the marker of a directory tpo made a run in
      .tpo.lock             held by the one tpo command working in the run

Every file is written whole and renamed into place (or, for the metrics,
truncated back to the last checkpoint on resume), so a kill never leaves a
file that a later run trusts half-written. Nothing is written through a
symlink: a run with one where tpo writes is refused (:func:`check_no_links`).
"""

from __future__ import annotations

import glob
import json
import math
import os
import re
import shutil
import sys
import tempfile
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import numpy as np

from tpo.algo import TPO
from tpo.algo.persist import FORMAT
from tpo.atomic import write_atomic
from tpo.errors import DamagedModel
from tpo.experiments.runspec import RunError, RunSpec
from tpo.locking import LOCK_FILE

METRICS = ("episode_return", "episode_length", "penalty", "violation_rate", "excluded",
           "policy_loss",
           "value_loss", "entropy", "approx_kl", "lr")
CHECKPOINTS = 10  # per run, at chunk boundaries
MARKER = ".tpo.run"  # written when tpo makes a run directory: --force may replace it
#: what tpo writes in a run, its lock aside (tpo.locking opens that without following a link)
WRITES = (MARKER, "config.toml", "metrics.csv", "eval.json", "tb", "checkpoints", "model")


class MetricsLog:
    """Per-update metrics to ``metrics.csv`` and TensorBoard (``tb/``).

    The CSV is appended chunk by chunk; opening the log first cuts it back to the
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
            # Rows that are not whole rows of this log (a cut-off line, damage) are
            # dropped; the checkpoint's rows are rewritten as they were.
            rows = path.read_text(errors="replace").splitlines()[1:]
            kept += [row for row in rows if row.count(",") == len(self.header) - 1
                     and row.split(",")[0].isdigit() and int(row.split(",")[0]) <= last_update]
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


def check_no_links(run_dir: Path, names: Iterable[str] = WRITES) -> None:
    """Raise :class:`RunError`, before anything is written, if one of ``names`` in
    ``run_dir`` or anything under it is a symlink: tpo writes through no link, so
    nothing outside the run is ever changed through one."""
    for name in names:
        link = _first_link(run_dir / name)
        if link is not None:
            raise RunError(f"{link} is a symlink; tpo writes through no link in a run "
                           "directory: replace it with the file or folder itself")


def _first_link(path: Path) -> Path | None:
    """``path`` if it is a symlink, else the first symlink under it, or None."""
    if path.is_symlink():
        return path
    for parent, folders, files in os.walk(path):  # lists links, follows none
        for name in sorted(folders + files):
            if (Path(parent) / name).is_symlink():
                return Path(parent) / name
    return None


def is_run(directory: Path) -> bool:
    """Whether ``directory`` is a tpo run: it holds tpo's marker (:data:`MARKER`),
    or, made before the marker, a saved model of a format tpo writes in ``model/``
    or ``checkpoints/update-N/``."""
    marker = directory / MARKER
    if marker.is_file() and not marker.is_symlink():
        return True
    return any(_saved_by_tpo(p) for p in [directory / "model",
                                          *directory.glob("checkpoints/update-*")])


def _saved_by_tpo(model: Path) -> bool:
    """Whether ``model`` holds a ``state.msgpack`` beside a ``model.json`` whose
    ``format`` is one tpo has written."""
    try:
        meta = json.loads((model / "model.json").read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return False
    found = meta.get("format") if isinstance(meta, dict) else None
    return type(found) is int and 1 <= found <= FORMAT and \
        (model / "state.msgpack").is_file()


def check_replaceable(out: Path) -> None:
    """Raise :class:`RunError` unless ``--force`` may replace ``out``: a tpo run
    (:func:`is_run`) holding nothing that tpo does not write, that is not the
    working directory or one of its parents, the home directory or a filesystem
    root."""
    where = out.resolve()
    if where == Path(where.anchor) or where == Path.home().resolve() \
            or Path.cwd().resolve().is_relative_to(where):
        raise RunError(f"--force will not replace {out}: it is the working directory or "
                       "one of its parents, the home directory or a filesystem root")
    if out.is_symlink():
        raise RunError(f"--force will not replace {out}: it is a symlink; give the run "
                       "directory itself")
    if not out.is_dir():
        raise RunError(f"--force will not replace {out}: not a run directory")
    if not is_run(out):
        raise RunError(f"--force will not replace {out}: it is not a tpo run (it has no "
                       f"{MARKER} marker and no saved model in model/ or checkpoints/)")
    foreign = _foreign(out)
    if foreign:
        raise RunError(f"--force will not replace {out}: it holds "
                       f"{str(foreign.relative_to(out))!r}, which tpo does not write in a run")


MODEL_FILES = ("model.json", "state.msgpack")
CHECKPOINT = re.compile(r"\.?update-\d+(\..+)?")  # a checkpoint, or its temporary


def _foreign(run: Path) -> Path | None:
    """The first file or directory in ``run`` that tpo does not write there (a
    symlink anywhere included), or None. A run holds its three files, marker and lock,
    ``model/`` and ``checkpoints/update-N/`` holding a saved model's two files,
    TensorBoard event files in ``tb/``, and tpo.atomic's temporaries of these."""
    for entry in sorted(run.iterdir()):
        name = entry.name
        if entry.is_symlink():
            return entry
        if name in ("config.toml", "metrics.csv", "eval.json", MARKER, LOCK_FILE) or \
                name.startswith((".config.toml.", ".metrics.csv.", ".eval.json.", f"{MARKER}.")):
            bad = None if entry.is_file() else entry
        elif name == "model" or name.startswith(".model."):
            bad = _not_a_model(entry)
        elif name == "checkpoints" and entry.is_dir():
            bad = next((b for point in sorted(entry.iterdir()) if (
                b := _not_a_model(point) if CHECKPOINT.fullmatch(point.name) else point)), None)
        elif name == "tb" and entry.is_dir():
            bad = next((p for p in sorted(entry.iterdir()) if p.is_symlink() or not p.is_file()
                        or not p.name.startswith("events.out.tfevents.")), None)
        else:
            bad = entry
        if bad is not None:
            return bad
    return None


def _not_a_model(directory: Path) -> Path | None:
    """``directory`` itself if it is not a directory, else its first entry that is
    not one of a saved model's two files."""
    if directory.is_symlink() or not directory.is_dir():
        return directory
    return next((p for p in sorted(directory.iterdir())
                 if p.is_symlink() or not p.is_file() or p.name not in MODEL_FILES), None)


class Replaced:
    """A run that ``--force`` replaces: its files, kept aside beside the run directory
    (which stays, with its lock) until the new run has started (:meth:`discard`) or
    failed to (:meth:`restore`)."""

    def __init__(self, run_dir: Path) -> None:
        self.run_dir = run_dir
        self.holder = Path(tempfile.mkdtemp(prefix=f".{run_dir.name}.replaced.",
                                            dir=run_dir.parent))
        try:
            for entry in _entries(run_dir):
                os.replace(entry, self.holder / entry.name)
        except BaseException:  # put back what moved, and say nothing was replaced
            self._put_back()
            raise

    def discard(self) -> None:
        shutil.rmtree(self.holder)

    def restore(self) -> None:
        """Remove the new run's files and put the old ones back."""
        for entry in _entries(self.run_dir):
            shutil.rmtree(entry) if entry.is_dir() else entry.unlink()
        self._put_back()

    def _put_back(self) -> None:
        for entry in self.holder.iterdir():
            os.replace(entry, self.run_dir / entry.name)
        self.holder.rmdir()


def check_not_stranded(run_dir: Path, own: Replaced | None = None) -> None:
    """Refuse to work on ``run_dir`` while an interrupted ``--force`` (a kill before
    the new run started) keeps the run it replaced aside."""
    for holder in run_dir.parent.glob(f".{glob.escape(run_dir.name)}.replaced.*"):
        if own is None or holder != own.holder:
            raise RunError(f"an interrupted --force left the run it replaced in {holder}; "
                           f"move its files back into {run_dir} or delete it, then retry")


def _entries(directory: Path) -> list[Path]:
    """Everything in ``directory`` but its lock."""
    return [p for p in directory.iterdir() if p.name != LOCK_FILE]


def create_run(out: str | Path, spec: RunSpec, force: bool = False
               ) -> tuple[Path, Replaced | None]:
    """Make the run directory with its marker and ``config.toml``, under the
    directory's lock (:func:`tpo.locking.exclusive`, which the caller holds). An
    existing run
    directory is kept unless ``force``, and then only a tpo run is replaced
    (:func:`check_replaceable`): its files are moved aside and returned, for
    :func:`train_run` to remove once the new run has started."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise RunError(f"--out {out} is a file, not a run directory")
    check_not_stranded(out)
    replaced = None
    if out.exists() and _entries(out):
        if not force:
            raise RunError(f"run directory {out} exists; pass --force to replace it "
                           "or --resume to continue it")
        check_replaceable(out)
        replaced = Replaced(out)
    try:
        out.mkdir(parents=True, exist_ok=True)
        write_atomic(out / MARKER, "a tpo run: tpo train --force may replace this directory\n")
        write_atomic(out / "config.toml", spec.to_toml())
    except BaseException:
        if replaced is not None:
            replaced.restore()
        raise
    return out, replaced


def _newest_good(saved: list[Path], trust_module: str | None) -> TPO:
    """The newest checkpoint that loads; a damaged one is reported and skipped."""
    for path in reversed(saved):
        try:
            return TPO.load(path, trust_module)
        except DamagedModel as err:
            print(f"tpo: warning: skipping checkpoint {path.name}: {err}", file=sys.stderr)
    raise RunError(f"every checkpoint of {saved[0].parent.parent} is damaged; train it "
                   "again with --force")


def _check_unchanged(spec: RunSpec, fresh: TPO, saved: TPO, run_dir: Path) -> None:
    """Refuse to resume when ``config.toml`` (whose model is ``fresh``) no longer
    describes the checkpoint's run."""
    ours, theirs = fresh.config.to_dict(), saved.config.to_dict()
    changed = [k for k in ours if ours[k] != theirs.get(k)]
    pairs = {"dag": (fresh.graph.spec, saved.graph.spec),
             "slack": (fresh.graph.slacks, saved.graph.slacks), "seed": (fresh.seed, saved.seed),
             "population": (fresh.population, saved.population),
             "steps": (spec.steps, saved.trainer.total_timesteps),
             "map/env": (fresh.env.to_spec(), saved.env.to_spec())}
    changed += [k for k, (a, b) in pairs.items() if a != b]
    if changed:
        raise RunError(f"{run_dir}/config.toml differs from the run's checkpoint in "
                       f"{', '.join(changed)}; put it back, or train a new run with it")


Progress = Callable[[TPO, dict[str, np.ndarray], int], None]


def train_run(run_dir: str | Path, episodes: int = 100, progress: Progress | None = None,
              chunk_updates: int = 16, replaced: Replaced | None = None,
              trust_module: str | None = None) -> dict[str, Any]:
    """Train the run in ``run_dir`` to its end, or resume it from its last checkpoint,
    checkpointing about :data:`CHECKPOINTS` times; then save the model and write
    ``eval.json``. A ``replaced`` run is removed once the first chunk has trained,
    and restored if anything fails before. ``trust_module``: see :meth:`TPO.load`."""
    run_dir = Path(run_dir)
    try:
        return _train(run_dir, episodes, progress, chunk_updates, replaced, trust_module)
    except BaseException:
        if replaced is not None and replaced.holder.exists():
            replaced.restore()
        raise


def _train(run_dir: Path, episodes: int, progress: Progress | None, chunk_updates: int,
           replaced: Replaced | None, trust_module: str | None) -> dict[str, Any]:
    check_not_stranded(run_dir, replaced)
    check_no_links(run_dir)
    saved = checkpoints(run_dir)
    spec = RunSpec.from_toml(run_dir / "config.toml", saved=bool(saved))
    model = spec.model()
    if saved:
        fresh, model = model, _newest_good(saved, trust_module)
        _check_unchanged(spec, fresh, model, run_dir)
    log = MetricsLog(run_dir, model.env.objectives, model.phases, spec.config.batch_size,
                     model.updates_done if saved else 0)

    def on_chunk(metrics: dict[str, np.ndarray], done: int) -> None:
        log.write(metrics, done)
        total = model.trainer.num_updates
        every = chunk_updates * max(1, math.ceil(total / CHECKPOINTS / chunk_updates))
        if done % every == 0 or done == total:
            model.save(run_dir / "checkpoints" / f"update-{done:06d}", overwrite=True)
        if replaced is not None and replaced.holder.exists():
            replaced.discard()  # the new run has started
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
