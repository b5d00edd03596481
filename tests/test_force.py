"""``tpo train --force`` replaces only a tpo run, and only once the new run has
started (issue 15, item 1): nothing a user made is deleted."""

import json
import os
from pathlib import Path

import pytest

from tpo.cli.main import main

TINY = ["--map", "small", "--dag", "A>G", "--slack", "0", "--steps", str(2 * 2048 * 2),
        "--episodes", "2", "--quiet"]


@pytest.fixture(scope="module")
def finished(tmp_path_factory) -> Path:
    """A finished tiny run (trained once for the module)."""
    out = tmp_path_factory.mktemp("runs") / "done"
    assert main(["train", *TINY, "--out", str(out)]) == 0
    return out


def copy_run(src: Path, dst: Path) -> Path:
    import shutil

    shutil.copytree(src, dst)
    return dst


@pytest.mark.parametrize("intruder", ["notes.txt", ".git", "data"])
def test_force_refuses_a_directory_with_files_tpo_does_not_write(finished, tmp_path, capsys,
                                                                 intruder):
    run = copy_run(finished, tmp_path / "run")
    (run / intruder).mkdir() if intruder != "notes.txt" else (run / intruder).write_text("x")
    before = sorted(p.name for p in run.iterdir())
    assert main(["train", *TINY, "--out", str(run), "--force"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"holds '{intruder}', which tpo does not write" in err
    assert sorted(p.name for p in run.iterdir()) == before


def test_force_refuses_a_directory_that_is_not_a_run(tmp_path, capsys):
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "config.toml").write_text("answer = 42\n")  # someone else's config.toml
    assert main(["train", *TINY, "--out", str(mine), "--force"]) == 2
    assert "is not a tpo run" in capsys.readouterr().err
    assert (mine / "config.toml").read_text() == "answer = 42\n"


@pytest.mark.parametrize("where", [".", "..", "~", "/"])
def test_force_never_replaces_the_working_directory_home_or_root(tmp_path, capsys,
                                                                 monkeypatch, where):
    work = tmp_path / "a" / "b"
    work.mkdir(parents=True)
    (work / "keep.txt").write_text("mine")
    monkeypatch.chdir(work)
    monkeypatch.setenv("HOME", str(tmp_path / "a"))
    out = os.path.expanduser(where)
    assert main(["train", *TINY, "--out", out, "--force"]) == 2
    err = capsys.readouterr().err
    assert "--force will not replace" in err and "working directory" in err
    assert (work / "keep.txt").read_text() == "mine"


def test_force_over_a_file_is_one_line(tmp_path, capsys):
    target = tmp_path / "file"
    target.write_text("mine")
    assert main(["train", *TINY, "--out", str(target), "--force"]) == 2
    assert "is a file, not a directory" in capsys.readouterr().err
    assert target.read_text() == "mine"


def test_a_failed_replacement_restores_the_old_run(finished, tmp_path, capsys, monkeypatch):
    run = copy_run(finished, tmp_path / "run")
    before = {p.relative_to(run): p.read_bytes() for p in run.rglob("*") if p.is_file()}
    import tpo.experiments.runs as runs

    def broken(*args, **kwargs):
        raise RuntimeError("the new run failed before its first update")

    monkeypatch.setattr(runs, "_train", broken)
    assert main(["train", *TINY, "--out", str(run), "--force"]) == 1  # a bug: one line
    after = {p.relative_to(run): p.read_bytes() for p in run.rglob("*") if p.is_file()}
    assert after == before
    assert [p.name for p in tmp_path.iterdir()] == ["run"]  # nothing left aside


def test_force_replaces_a_finished_run_and_leaves_nothing_aside(finished, tmp_path):
    run = copy_run(finished, tmp_path / "run")
    (run / "eval.json").write_text("{}")  # the old run's result, to be replaced
    assert main(["train", *TINY, "--out", str(run), "--force", "--seed", "1"]) == 0
    assert json.loads((run / "eval.json").read_text())["exact"]
    assert "seed = 1" in (run / "config.toml").read_text()
    assert [p.name for p in tmp_path.iterdir()] == ["run"]
