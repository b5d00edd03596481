"""A pool of worker processes for independent compiled jobs (e.g. sweep panels):
one XLA thread per worker, one worker per core (the best total on small batches,
docs/tpo-algorithm.md), progress reported to the parent, and workers that die
with their parent."""

from __future__ import annotations

import ctypes
import os
import signal
import sys
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor, wait
from multiprocessing import get_context
from queue import Empty
from typing import Any

SINGLE_THREAD = "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"
PR_SET_PDEATHSIG = 1  # prctl(2): the signal a process gets when its parent dies

_progress_queue: Any = None  # a worker's queue of (job name, fraction) for the parent


def report_progress(name: str, fraction: float) -> None:
    """Called in a worker: job ``name`` is ``fraction`` done."""
    if _progress_queue is not None:
        _progress_queue.put((name, fraction))


def _init_worker(queue: Any, parent: int) -> None:
    """A worker: one XLA thread; progress to ``queue``; on Linux, killed with its
    parent (a SIGKILLed parent must not leave workers writing into a directory
    that its restart resumes)."""
    global _progress_queue
    _progress_queue = queue
    os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {SINGLE_THREAD}".strip()
    if sys.platform.startswith("linux"):
        # The signal follows the *thread* that started the worker: ProcessPoolExecutor
        # starts workers from submit(), in the caller's (main) thread.
        if ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL):
            raise OSError(ctypes.get_errno(), "prctl(PR_SET_PDEATHSIG) failed")
        if os.getppid() != parent:  # the parent died before prctl took effect
            os._exit(1)


def run_jobs(fn: Callable[..., Any], jobs: Sequence[tuple[str, tuple]], workers: int,
             progress: Callable[[str, float], None] | None = None) -> dict[str, Any]:
    """``fn(*args)`` of every ``(name, args)`` job in spawned worker processes;
    ``progress(name, fraction)`` as workers report (:func:`report_progress`) and
    when a job finishes. Returns ``{name: result}``."""
    results: dict[str, Any] = {}
    if not jobs:
        return results
    ctx = get_context("spawn")
    queue = ctx.Queue()
    with ProcessPoolExecutor(max_workers=min(workers, len(jobs)), mp_context=ctx,
                             initializer=_init_worker, initargs=(queue, os.getpid())) as pool:
        pending = {pool.submit(fn, *args): name for name, args in jobs}
        while pending:
            while True:
                try:
                    name, fraction = queue.get_nowait()
                except Empty:
                    break
                if progress is not None:
                    progress(name, fraction)
            for future in [f for f in pending if f.done()]:
                name = pending.pop(future)
                results[name] = future.result()
                if progress is not None:
                    progress(name, 1.0)
            if pending:
                wait(pending, timeout=0.5)
    return results
