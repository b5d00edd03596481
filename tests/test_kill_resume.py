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


def tpo(*args: str, **kwargs) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "tpo.cli.main", *args],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, **kwargs)


@pytest.mark.slow
def test_sigkill_at_a_random_moment_then_resume_gives_the_uninterrupted_result(tmp_path):
    whole, killed = tmp_path / "whole", tmp_path / "killed"
    assert tpo(*ARGS, "--out", str(whole)).wait() == 0

    proc = tpo(*ARGS, "--out", str(killed))
    deadline = time.monotonic() + 300
    while not (killed / "checkpoints").exists() or not any((killed / "checkpoints").iterdir()):
        assert proc.poll() is None and time.monotonic() < deadline, proc.stderr.read()
        time.sleep(0.05)
    time.sleep(random.Random(os.getpid()).uniform(0.0, 2.0))  # mid-phase or between
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert not (killed / "eval.json").exists(), "the run finished before the kill"

    resumed = tpo("train", "--resume", str(killed), "--episodes", "4", "--quiet")
    assert resumed.wait() == 0, resumed.stderr.read()
    assert json.loads((killed / "eval.json").read_text()) == \
        json.loads((whole / "eval.json").read_text())
    assert (killed / "metrics.csv").read_text() == (whole / "metrics.csv").read_text()
    a, b = TPO.load(whole / "model"), TPO.load(killed / "model")
    assert (whole / "model" / "state.msgpack").read_bytes() == \
        (killed / "model" / "state.msgpack").read_bytes(), (a.num_timesteps, b.num_timesteps)


REPRODUCE = ["reproduce", "--map", "small", "--slacks", "0,5", "--seeds", "1", "--steps",
             "40000", "--workers", "2", "--quiet"]


def children(pid: int) -> list[int]:
    """The pids whose parent is ``pid`` (Linux /proc)."""
    found = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
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
    whole, killed = tmp_path / "whole", tmp_path / "killed"
    assert tpo(*REPRODUCE, "--out", str(whole)).wait() == 0

    proc = tpo(*REPRODUCE, "--out", str(killed))
    deadline = time.monotonic() + 600
    while not list((killed / "panels").glob("*.json")):  # a panel done, others running
        assert proc.poll() is None and time.monotonic() < deadline, proc.stderr.read()
        time.sleep(0.05)
    time.sleep(random.Random(os.getpid()).uniform(0.0, 3.0))
    workers = children(proc.pid)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert not (killed / "results.csv").exists(), "the reproduction finished before the kill"
    deadline = time.monotonic() + 10
    while any(alive(w) for w in workers):  # the workers die with their parent
        assert time.monotonic() < deadline, [w for w in workers if alive(w)]
        time.sleep(0.1)

    resumed = tpo(*REPRODUCE, "--out", str(killed))
    assert resumed.wait() == 0, resumed.stderr.read()
    assert (killed / "results.csv").read_text() == (whole / "results.csv").read_text()
    assert (killed / "report.md").read_text() == (whole / "report.md").read_text()
