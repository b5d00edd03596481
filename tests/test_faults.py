"""System faults at the command line (issue 15, item 6): a full disk or an
unwritable directory ends in one line, leaves nothing half-written, and a run
stopped by one resumes to the same result once the fault is gone."""

import errno
import json
import os

import pytest

import tpo.atomic
from tpo.cli.main import main

# 34 updates: checkpoints after updates 16, 32 and 34.
ARGS = ["--map", "small", "--dag", "A>G", "--slack", "0", "--steps", str(2048 * 34),
        "--episodes", "2", "--quiet"]


def fsync_failing_in(monkeypatch, marker: str) -> None:
    """``os.fsync`` as tpo's atomic writers call it, failing with ENOSPC for files
    whose path contains ``marker``."""
    real = os.fsync

    def fsync(fd):
        if marker in os.readlink(f"/proc/self/fd/{fd}"):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return real(fd)

    monkeypatch.setattr(tpo.atomic.os, "fsync", fsync)


@pytest.mark.slow
def test_a_full_disk_mid_run_is_one_line_and_the_run_resumes_identically(
        tmp_path, capsys, monkeypatch):
    whole = tmp_path / "whole"
    assert main(["train", *ARGS, "--out", str(whole)]) == 0
    run = tmp_path / "run"
    with monkeypatch.context() as m:
        fsync_failing_in(m, "update-000032")
        capsys.readouterr()
        assert main(["train", *ARGS, "--out", str(run)]) == 2
    err = capsys.readouterr().err
    assert err == "tpo: error: No space left on device\n", err
    assert sorted(p.name for p in (run / "checkpoints").iterdir()) == ["update-000016"]
    assert not [p for p in run.rglob(".*") if p.name != ".tpo.lock"]  # no temporaries
    assert main(["train", "--resume", str(run), "--quiet", "--episodes", "2"]) == 0
    assert json.loads((run / "eval.json").read_text()) == \
        json.loads((whole / "eval.json").read_text())
    assert (run / "metrics.csv").read_text() == (whole / "metrics.csv").read_text()


def test_an_unwritable_out_is_one_line(tmp_path, capsys, monkeypatch):
    def refuse(*args, **kwargs):
        raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), str(tmp_path / "x"))

    monkeypatch.setattr(tpo.atomic.tempfile, "mkstemp", refuse)
    assert main(["train", *ARGS, "--out", str(tmp_path / "x")]) == 2
    assert capsys.readouterr().err == f"tpo: error: Permission denied: {tmp_path / 'x'}\n"
    assert not (tmp_path / "x").exists()  # the directory made for the run is gone


def test_a_bug_is_one_line_and_debug_shows_its_traceback(tmp_path, capsys, monkeypatch):
    import tpo.experiments.runs as runs

    def bug(*args, **kwargs):
        raise ZeroDivisionError("a bug\nover two lines")

    monkeypatch.setattr(runs, "_train", bug)
    assert main(["train", *ARGS, "--out", str(tmp_path / "r")]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "internal error ZeroDivisionError: a bug over two" in err
    with pytest.raises(ZeroDivisionError):
        main(["--debug", "train", *ARGS, "--out", str(tmp_path / "r2")])
