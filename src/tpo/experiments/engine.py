"""The sweep engine: independent units of work run by a backend while the driver
alone writes their results.

A unit is one compiled, vmapped program (a group of slack × seed runs, e.g. one
panel of the reproduction): ``fn(*args, link)`` returning a JSON-able record.
Through its :class:`Link` a running unit reports progress and keeps its
checkpoint where the driver can read it, so a unit whose worker dies is retried
from its last checkpoint. Two backends run units:

- :class:`LocalBackend`: spawned worker processes on this machine, one XLA
  thread each (the best total on small batches, docs/tpo-algorithm.md), killed
  with their parent; checkpoints in the output directory.
- :class:`RayBackend`: each unit a Ray task on a running cluster, retried when
  its worker dies; checkpoints on shared storage (``storage``) or returned to
  the driver through an actor on the driver's node.

:func:`run_units` is the driver: it skips units whose record is in the output
directory, writes each record there atomically as its unit finishes (so a killed
sweep restarted on its directory redoes nothing finished) and deletes the unit's
checkpoint (tpo's own file) after.
"""

from __future__ import annotations

import ctypes
import hashlib
import json
import logging
import os
import signal
import socket
import sys
import tempfile
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor, wait
from dataclasses import dataclass, field
from multiprocessing import get_context
from pathlib import Path
from queue import Empty
from typing import Any

from tpo.atomic import write_atomic
from tpo.errors import TPOError

SINGLE_THREAD = "--xla_cpu_multi_thread_eigen=false"
PR_SET_PDEATHSIG = 1  # prctl(2): the signal a process gets when its parent dies
CHECKPOINT_SECONDS = 60.0  # a running unit's checkpoint is at most this old
RAY_RETRIES = 3  # times a unit whose worker died is started again


def single_thread_flags() -> str:
    """``XLA_FLAGS`` of a worker: the caller's flags (e.g. an ISA cap) and one thread."""
    return f"{os.environ.get('XLA_FLAGS', '')} {SINGLE_THREAD}".strip()


@dataclass(frozen=True)
class Unit:
    """One unit of work: ``fn(*args, link)`` returns its JSON-able record. ``name``
    is its file name in the output directory and its progress key."""

    name: str
    fn: Callable[..., dict[str, Any]]
    args: tuple


class Link:
    """What a running unit sees of the engine: :meth:`progress`, and a checkpoint
    (:meth:`load`, :meth:`save`, at most ``every`` seconds apart; ``where`` names it
    in messages) that outlives the worker."""

    def __init__(self, name: str, every: float) -> None:
        self.name, self.every = name, every

    @property
    def where(self) -> str:
        return f"the checkpoint of unit {self.name}"

    def progress(self, fraction: float) -> None:
        raise NotImplementedError

    def load(self) -> bytes | None:
        raise NotImplementedError

    def save(self, data: bytes) -> None:
        raise NotImplementedError


class FileLink(Link):
    """A checkpoint in a file; progress to ``report`` (if any)."""

    def __init__(self, name: str, every: float, path: Path,
                 report: Callable[[str, float], None] | None = None) -> None:
        super().__init__(name, every)
        self.path, self.report = Path(path), report

    @property
    def where(self) -> str:
        return str(self.path)

    def progress(self, fraction: float) -> None:
        if self.report is not None:
            self.report(self.name, fraction)

    def load(self) -> bytes | None:
        return self.path.read_bytes() if self.path.exists() else None

    def save(self, data: bytes) -> None:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        write_atomic(self.path, data)


@dataclass
class Tracker:
    """The driver's view of running units: each unit's fraction done, and each
    attempt at it as ``[pid of its worker, the fraction it started from]`` (the
    start is its first report; a unit reports where it stands as it starts)."""

    fractions: dict[str, float]
    attempts: dict[str, list[list]] = field(default_factory=dict)
    on_change: Callable[[Tracker], None] | None = None

    def begin(self, name: str, pid: int) -> None:
        attempts = self.attempts.setdefault(name, [])
        if not attempts or attempts[-1][0] != pid:  # else known from its result
            attempts.append([pid, None])

    def finished(self, name: str, pid: int, start: float | None) -> None:
        """The attempt of worker ``pid`` that finished ``name`` started at ``start``
        (for backends whose reports may come after the result)."""
        attempts = self.attempts.setdefault(name, [])
        if not attempts or attempts[-1][0] != pid:
            attempts.append([pid, None])
        if attempts[-1][1] is None:
            attempts[-1][1] = start

    def progress(self, name: str, fraction: float) -> None:
        attempts = self.attempts.get(name)
        if attempts and attempts[-1][1] is None:
            attempts[-1][1] = fraction
        if fraction > self.fractions[name]:  # a late report never moves a unit back
            self.fractions[name] = fraction
            if self.on_change is not None:
                self.on_change(self)


Done = Callable[[str, dict[str, Any]], None]


class Backend:
    """Runs units, calling ``done(name, record)`` in the driver as each finishes."""

    every: float = CHECKPOINT_SECONDS

    def run(self, units: Sequence[Unit], tracker: Tracker, done: Done, folder: Path) -> None:
        raise NotImplementedError

    def forget(self, name: str, folder: Path) -> None:
        """Delete the checkpoint of the finished unit ``name``."""
        (folder / f"{name}.ckpt").unlink(missing_ok=True)


def run_units(units: Sequence[Unit], backend: Backend, folder: Path,
              progress: Callable[[Tracker], None] | None = None) -> dict[str, dict[str, Any]]:
    """Every unit's record: read from ``folder/NAME.json`` if it finished before,
    else run by ``backend`` and written there (its checkpoint: ``folder/NAME.ckpt``
    unless the backend keeps it elsewhere). ``progress(tracker)`` at the start and
    whenever a unit advances."""
    folder.mkdir(parents=True, exist_ok=True)
    records = {u.name: read_record(folder / f"{u.name}.json") for u in units
               if (folder / f"{u.name}.json").exists()}
    tracker = Tracker({u.name: float(u.name in records) for u in units}, on_change=progress)
    if progress is not None:
        progress(tracker)

    def done(name: str, record: dict[str, Any]) -> None:
        write_atomic(folder / f"{name}.json", json.dumps(record))
        backend.forget(name, folder)
        records[name] = record
        tracker.progress(name, 1.0)

    todo = [u for u in units if u.name not in records]
    if todo:
        backend.run(todo, tracker, done, folder)
    return {u.name: records[u.name] for u in units}


def read_record(path: Path) -> dict[str, Any]:
    """The record a unit wrote to ``path`` (a clear error if it is not one)."""
    try:
        record = json.loads(path.read_text())
    except (UnicodeDecodeError, ValueError) as err:
        raise TPOError(f"{path} is not a unit's record ({err}); delete it to run the unit "
                       "again") from None
    if not isinstance(record, dict):
        raise TPOError(f"{path} is not a unit's record; delete it to run the unit again")
    return record


# -------------------------------------------------------------------- local
_events: Any = None  # in a local worker: the queue of (kind, unit name, value) to the driver


def _report(name: str, fraction: float) -> None:
    _events.put(("progress", name, fraction))


def _init_worker(queue: Any, parent: int, cache: str) -> None:
    """A local worker: one XLA thread; compiled programs shared with the other workers
    through the folder ``cache`` (JAX's persistent cache, unless the caller names
    one: a panel's units compile the same program); events to ``queue``; on Linux,
    killed with its parent (a SIGKILLed driver must not leave workers writing into a
    directory that its restart resumes)."""
    global _events
    _events = queue
    os.environ["XLA_FLAGS"] = single_thread_flags()
    os.environ.setdefault("JAX_COMPILATION_CACHE_DIR", cache)
    # Ctrl-C reaches the whole process group: the driver says "interrupted"; a worker
    # ends without a traceback of its own.
    signal.signal(signal.SIGINT, lambda *_: os._exit(130))
    if sys.platform.startswith("linux"):
        # The signal follows the *thread* that started the worker: ProcessPoolExecutor
        # starts workers from submit(), in the caller's (main) thread.
        if ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL):
            raise OSError(ctypes.get_errno(), "prctl(PR_SET_PDEATHSIG) failed")
        if os.getppid() != parent:  # the parent died before prctl took effect
            os._exit(1)


def _run_local(unit: Unit, path: Path, every: float) -> dict[str, Any]:
    _events.put(("begin", unit.name, os.getpid()))
    return unit.fn(*unit.args, FileLink(unit.name, every, path, _report))


@dataclass
class LocalBackend(Backend):
    """``workers`` spawned processes on this machine; checkpoints in the folder of
    the records."""

    workers: int = 2
    every: float = CHECKPOINT_SECONDS

    def run(self, units: Sequence[Unit], tracker: Tracker, done: Done, folder: Path) -> None:
        ctx = get_context("spawn")
        queue = ctx.Queue()

        def drain() -> None:
            while True:
                try:
                    kind, name, value = queue.get_nowait()
                except Empty:
                    return
                (tracker.begin if kind == "begin" else tracker.progress)(name, value)

        with tempfile.TemporaryDirectory(prefix="tpo-xla-") as cache, ProcessPoolExecutor(
                max_workers=min(self.workers, len(units)), mp_context=ctx,
                initializer=_init_worker, initargs=(queue, os.getpid(), cache)) as pool:
            pending = {pool.submit(_run_local, u, folder / f"{u.name}.ckpt",
                                   self.every): u.name for u in units}
            while pending:
                drain()
                for future in [f for f in pending if f.done()]:
                    drain()
                    done(pending.pop(future), future.result())
                if pending:
                    wait(pending, timeout=0.5)


# ---------------------------------------------------------------------- ray
class RayLink(Link):
    """A Ray task's link: progress to the driver's store actor; the checkpoint in a
    file under ``storage`` (shared storage) or, without it, sent to the store, the
    unit's last one handed to the task by the driver (``data``).

    Nothing here waits on the store: a task blocked in ``ray.get`` lends its CPU
    to another task, and the node would run more units than it has CPUs. So a
    checkpoint sent to the store may be lost with its worker (the unit then
    resumes from the one before), and the attempt's start (``first``, its first
    report) also travels back with its result."""

    def __init__(self, name: str, every: float, store: Any, storage: Path | None,
                 data: bytes | None) -> None:
        super().__init__(name, every)
        self.store, self.storage, self.data = store, storage, data
        self.first: float | None = None

    @property
    def where(self) -> str:
        if self.storage is not None:
            return str(self.storage / f"{self.name}.ckpt")
        return super().where

    def _file(self) -> FileLink:
        return FileLink(self.name, self.every, self.storage / f"{self.name}.ckpt")

    def progress(self, fraction: float) -> None:
        if self.first is None:
            self.first = fraction
        self.store.progress.remote(self.name, fraction)

    def load(self) -> bytes | None:
        return self.data if self.storage is None else self._file().load()

    def save(self, data: bytes) -> None:
        if self.storage is None:
            self.store.save.remote(self.name, data)
        else:
            self._file().save(data)


class Store:
    """A Ray actor on the driver's node: the units' progress and attempts for the
    driver to poll, and their checkpoints as files in the driver's output folder."""

    def __init__(self, folder: str) -> None:
        self.folder = Path(folder)
        self.events: list[tuple[str, str, float]] = []

    def begin(self, name: str, pid: int) -> None:
        self.events.append(("begin", name, pid))

    def progress(self, name: str, fraction: float) -> None:
        self.events.append(("progress", name, fraction))

    def take(self) -> list[tuple[str, str, float]]:
        events, self.events = self.events, []
        return events

    def save(self, name: str, data: bytes) -> None:
        write_atomic(self.folder / f"{name}.ckpt", data)


def _run_ray(unit: Unit, store: Any, storage: str | None, every: float, data: bytes | None
             ) -> tuple[dict[str, Any], list]:
    """A unit as a Ray task: its record, and its attempt (pid, start)."""
    store.begin.remote(unit.name, os.getpid())
    link = RayLink(unit.name, every, store, None if storage is None else Path(storage), data)
    record = unit.fn(*unit.args, link)
    return record, [os.getpid(), link.first]


@dataclass
class RayBackend(Backend):
    """Each unit a Ray task (one CPU, one XLA thread) on the cluster at ``address``
    (``auto``: the one this machine belongs to), started again from its checkpoint
    (up to ``RAY_RETRIES`` times) when its worker or node dies. Checkpoints: files
    under ``storage`` (a folder every node and the driver share), or without it,
    sent to the driver."""

    address: str = "auto"
    storage: Path | None = None
    every: float = CHECKPOINT_SECONDS

    def _checkpoints(self, folder: Path) -> Path:
        """Where the checkpoints of the units recorded in ``folder`` live."""
        if self.storage is None:
            return folder
        key = hashlib.sha256(str(folder.resolve()).encode()).hexdigest()[:16]
        return self.storage / f"tpo-{key}"

    def forget(self, name: str, folder: Path) -> None:
        (self._checkpoints(folder) / f"{name}.ckpt").unlink(missing_ok=True)

    def run(self, units: Sequence[Unit], tracker: Tracker, done: Done, folder: Path) -> None:
        ray = _import_ray()
        if self.storage is not None:
            self._checkpoints(folder).mkdir(exist_ok=True)
        started = not ray.is_initialized()
        if started:
            try:
                ray.init(address=self.address, log_to_driver=False,
                         logging_level=logging.WARNING,
                         runtime_env={"env_vars": {"XLA_FLAGS": single_thread_flags()}})
            except (ConnectionError, RuntimeError, ValueError) as err:
                raise TPOError(f"cannot connect to the Ray cluster at {self.address}: "
                               f"{str(err).splitlines()[0]}") from None
        try:
            self._run(ray, units, tracker, done, self._checkpoints(folder))
        finally:
            if started:
                ray.shutdown()

    def _run(self, ray: Any, units: Sequence[Unit], tracker: Tracker, done: Done,
             checkpoints: Path) -> None:
        from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

        here = NodeAffinitySchedulingStrategy(ray.get_runtime_context().get_node_id(),
                                              soft=False)
        store = ray.remote(num_cpus=0)(Store).options(scheduling_strategy=here) \
            .remote(str(checkpoints))
        # Retried here, not by Ray: a retried task would get its first arguments again.
        task = ray.remote(num_cpus=1, max_retries=0)(_run_ray)
        storage = None if self.storage is None else str(checkpoints)

        def submit(unit: Unit) -> Any:
            data = None if storage is not None else FileLink(
                unit.name, self.every, checkpoints / f"{unit.name}.ckpt").load()
            return task.remote(unit, store, storage, self.every, data)

        def drain() -> None:
            for kind, name, value in ray.get(store.take.remote()):
                (tracker.begin if kind == "begin" else tracker.progress)(name, value)

        pending = {submit(u): u for u in units}
        retries = dict.fromkeys((u.name for u in units), 0)
        try:
            while pending:
                ready, _ = ray.wait(list(pending), num_returns=1, timeout=0.5)
                drain()
                for ref in ready:
                    unit = pending.pop(ref)
                    try:
                        record, attempt = ray.get(ref)
                    except ray.exceptions.RayTaskError as err:  # the unit raised
                        cause = err.cause
                        if isinstance(cause, TPOError):
                            raise cause from None
                        raise TPOError(f"unit {unit.name} failed on the Ray cluster: "
                                       f"{type(cause).__name__}: {cause}") from None
                    except ray.exceptions.RayError as err:  # its worker or node died
                        if retries[unit.name] == RAY_RETRIES:
                            raise TPOError(f"unit {unit.name} failed on the Ray cluster "
                                           f"{RAY_RETRIES + 1} times: "
                                           f"{str(err).splitlines()[0]}") from None
                        retries[unit.name] += 1
                        drain()  # the store has written every checkpoint that reached it
                        pending[submit(unit)] = unit
                        continue
                    drain()
                    tracker.finished(unit.name, *attempt)
                    done(unit.name, record)
        finally:
            for ref in pending:
                ray.cancel(ref, force=True)
            ray.kill(store)


def _import_ray() -> Any:
    try:
        import ray
    except ImportError:
        raise TPOError("the ray backend needs Ray: pip install 'tpo[ray]'") from None
    return ray


def backend(name: str, workers: int | None = None, address: str | None = None,
            storage: str | None = None) -> Backend:
    """The backend a command line names: ``local`` (``workers`` processes, default 2)
    or ``ray`` (the cluster at ``address``, checkpoints under ``storage`` if given),
    checked before anything is made: a Ray address must answer."""
    if name == "local":
        if address is not None or storage is not None:
            raise TPOError("--address and --storage are options of --backend ray")
        if workers is not None and workers < 1:
            raise TPOError("--workers must be at least 1")
        return LocalBackend(2 if workers is None else workers)
    if name == "ray":
        if workers is not None:
            raise TPOError("--workers is an option of --backend local (a Ray cluster runs "
                           "as many units as it has CPUs)")
        if storage is not None and not Path(storage).is_dir():
            raise TPOError(f"--storage {storage} is not a directory")
        _check_address(address or "auto")
        return RayBackend(address or "auto", None if storage is None else Path(storage))
    raise TPOError(f"unknown backend {name!r}: choose local or ray")


def _check_address(address: str) -> None:
    """Fail fast, in one line, where ``ray.init`` would retry for minutes: an address
    that is not ``auto`` or ``HOST:PORT``, or nothing listening there."""
    if address == "auto":
        return
    host, sep, port = address.rpartition(":")
    if not sep or not host or "/" in address or not port.isdigit():
        raise TPOError(f"--address {address!r}: give the cluster's HOST:PORT (what `ray start "
                       "--head` prints), or auto")
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=5).close()
    except OSError as err:
        raise TPOError(f"cannot connect to the Ray cluster at {address}: "
                       f"{err.strerror or err}") from None

