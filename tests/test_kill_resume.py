"""Issue 7: a run killed with SIGKILL at a random moment resumes to exactly the
result of an uninterrupted run (same seed, same machine)."""

import json
import os
import random
import signal
import subprocess
import sys
import time

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
