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
    assert not [p for p in run.rglob(".*") if p.name not in (".tpo.lock", ".tpo.run")
                ]  # no temporaries
    assert main(["train", "--resume", str(run), "--quiet", "--episodes", "2"]) == 0
    assert json.loads((run / "eval.json").read_text()) == \
        json.loads((whole / "eval.json").read_text())
    assert (run / "metrics.csv").read_text() == (whole / "metrics.csv").read_text()


def test_an_unwritable_out_is_one_line(tmp_path, capsys, monkeypatch):
    def refuse(*args, **kwargs):
        raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), str(tmp_path / "x"))

    monkeypatch.setattr(tpo.atomic.tempfile, "mkstemp", refuse)
    assert main(["train", *ARGS, "--out", str(tmp_path / "x")]) == 2
    # The file tpo was writing (its run marker, the first), not mkstemp's temporary.
    assert capsys.readouterr().err == (f"tpo: error: Permission denied: "
                                       f"{tmp_path / 'x' / '.tpo.run'}\n")
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


@pytest.fixture(scope="module")
def stopped(tmp_path_factory):
    """A run stopped after update 32 (its checkpoints 16 and 32 kept), and the same
    run trained whole."""
    root = tmp_path_factory.mktemp("stopped")
    assert main(["train", *ARGS, "--out", str(root / "whole")]) == 0
    run = root / "run"
    import shutil

    shutil.copytree(root / "whole", run)
    for p in [run / "model", run / "checkpoints" / "update-000034", run / "eval.json"]:
        shutil.rmtree(p) if p.is_dir() else p.unlink()
    return root


def _copy(stopped, tmp_path):
    import shutil

    return shutil.copytree(stopped / "run", tmp_path / "run")


@pytest.mark.parametrize("damage", ["truncate", "flip", "meta"])
def test_a_damaged_last_checkpoint_falls_back_to_the_one_before(stopped, tmp_path, capsys,
                                                                damage):
    run = _copy(stopped, tmp_path)
    last = run / "checkpoints" / "update-000032"
    state = last / "state.msgpack"
    blob = state.read_bytes()
    if damage == "truncate":
        state.write_bytes(blob[: len(blob) // 2])
    elif damage == "flip":
        state.write_bytes(blob[:100] + bytes([blob[100] ^ 1]) + blob[101:])
    else:
        (last / "model.json").write_text("{ not json")
    assert main(["train", "--resume", str(run), "--quiet", "--episodes", "2"]) == 0
    assert "skipping checkpoint update-000032" in capsys.readouterr().err
    assert json.loads((run / "eval.json").read_text()) == \
        json.loads((stopped / "whole" / "eval.json").read_text())


def test_an_edited_config_is_refused_on_resume_naming_the_keys(stopped, tmp_path, capsys):
    run = _copy(stopped, tmp_path)
    config = run / "config.toml"
    text = config.read_text()
    population = next(line for line in text.splitlines() if line.startswith("population"))
    config.write_text(text.replace("learning_rate = 0.001", "learning_rate = 0.01")
                      .replace("seed = 0", "seed = 3").replace(population, "population = 5"))
    before = (run / "metrics.csv").read_text()
    assert main(["train", "--resume", str(run), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and \
        "differs from the run's checkpoint in learning_rate, seed, population" in err, err
    assert (run / "metrics.csv").read_text() == before
