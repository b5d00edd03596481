"""Issue 7: a run killed with SIGKILL at a random moment resumes to exactly the
result of an uninterrupted run (same seed, same machine)."""

import json
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tpo.algo import TPO

ARGS = ["train", "--map", "small", "--dag", "M>A>G", "--slack", "100,0", "--seed", "3",
        "--steps", str(3 * 2048 * 40), "--episodes", "4", "--quiet"]


def tpo(*args: str, log: Path) -> subprocess.Popen:
    """``tpo ARGS`` in a subprocess, its stderr to the file ``log`` (a pipe nobody
    reads could fill up and block it)."""
    with open(log, "w") as err:
        return subprocess.Popen([sys.executable, "-m", "tpo.cli.main", *args],
                                stdout=subprocess.DEVNULL, stderr=err)


@pytest.mark.slow
def test_sigkill_at_a_random_moment_then_resume_gives_the_uninterrupted_result(tmp_path):
    whole, killed, log = tmp_path / "whole", tmp_path / "killed", tmp_path / "log"
    assert tpo(*ARGS, "--out", str(whole), log=log).wait() == 0, log.read_text()

    proc = tpo(*ARGS, "--out", str(killed), log=log)
    deadline = time.monotonic() + 300
    while not (killed / "checkpoints").exists() or not any((killed / "checkpoints").iterdir()):
        assert proc.poll() is None and time.monotonic() < deadline, log.read_text()
        time.sleep(0.05)
    time.sleep(random.Random(os.getpid()).uniform(0.0, 2.0))  # mid-phase or between
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert not (killed / "eval.json").exists(), "the run finished before the kill"

    resumed = tpo("train", "--resume", str(killed), "--episodes", "4", "--quiet", log=log)
    assert resumed.wait() == 0, log.read_text()
    assert json.loads((killed / "eval.json").read_text()) == \
        json.loads((whole / "eval.json").read_text())
    assert (killed / "metrics.csv").read_text() == (whole / "metrics.csv").read_text()
    a, b = TPO.load(whole / "model"), TPO.load(killed / "model")
    assert (whole / "model" / "state.msgpack").read_bytes() == \
        (killed / "model" / "state.msgpack").read_bytes(), (a.num_timesteps, b.num_timesteps)


REPRODUCE = ["reproduce", "--map", "small", "--slacks", "0,5", "--seeds", "1", "--steps",
             "40000", "--workers", "2", "--quiet"]


def workers(pid: int) -> list[int]:
    """The pids of ``pid``'s multiprocessing workers (children started by
    ``spawn_main``; not the resource tracker, which outlives them by design)."""
    found = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            ppid = int(stat.read_text().rsplit(")", 1)[1].split()[1])
            cmdline = (stat.parent / "cmdline").read_bytes()
        except OSError:
            continue
        if ppid == pid and b"spawn_main" in cmdline:
            found.append(int(stat.parent.name))
    return found


def alive(pid: int) -> bool:
    """Whether ``pid`` runs (a zombie does not: it has exited unreaped)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


@pytest.mark.slow
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_sigkilled_reproduction_leaves_no_workers_and_resumes_to_the_same_results(tmp_path):
    whole, killed, log = tmp_path / "whole", tmp_path / "killed", tmp_path / "log"
    assert tpo(*REPRODUCE, "--out", str(whole), log=log).wait() == 0, log.read_text()

    proc = tpo(*REPRODUCE, "--out", str(killed), log=log)
    deadline = time.monotonic() + 600
    while not list((killed / "panels").glob("*.json")):  # a panel done, others running
        assert proc.poll() is None and time.monotonic() < deadline, log.read_text()
        time.sleep(0.05)
    time.sleep(random.Random(os.getpid()).uniform(0.0, 3.0))
    running = workers(proc.pid)
    assert len(running) == 2, running
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert not (killed / "results.csv").exists(), "the reproduction finished before the kill"
    # The workers die with their parent at once (one has just begun its next panel,
    # so it would otherwise train and write for many seconds).
    deadline = time.monotonic() + 2
    while any(alive(w) for w in running):
        assert time.monotonic() < deadline, [w for w in running if alive(w)]
        time.sleep(0.05)

    resumed = tpo(*REPRODUCE, "--out", str(killed), log=log)
    assert resumed.wait() == 0, log.read_text()
    assert (killed / "results.csv").read_text() == (whole / "results.csv").read_text()
    assert (killed / "report.md").read_text() == (whole / "report.md").read_text()
