"""``tpo train --force`` replaces only a tpo run, and only once the new run has
started (issue 15, item 1): nothing a user made is deleted."""

import json
import os
import shutil
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


NOT_A_RUN = ("it is not a tpo run (it has no .tpo.run marker and no saved model in model/ "
             "or checkpoints/)")


@pytest.mark.parametrize("files", [
    {"config.toml": 'map = "small"\n'},  # a user's config.toml that tpo would train
    {"config.toml": ""},
    {"config.toml": "answer = 42\n"},
    {"config.toml": 'map = "small"\n', "notes.txt": "mine", "data/raw.csv": "1,2\n"},
    {"notes.txt": "mine", "data/raw.csv": "1,2\n"},
    {"model/model.json": '{"format": 99}', "model/state.msgpack": "x"},  # not tpo's format
])
def test_force_refuses_a_directory_that_is_not_a_run(tmp_path, capsys, files):
    mine = tmp_path / "mine"
    for name, text in files.items():
        (mine / name).parent.mkdir(parents=True, exist_ok=True)
        (mine / name).write_text(text)
    assert main(["train", *TINY, "--out", str(mine), "--force"]) == 2
    assert capsys.readouterr().err == f"tpo: error: --force will not replace {mine}: " \
        f"{NOT_A_RUN}\n"
    assert {str(p.relative_to(mine)): p.read_text() for p in mine.rglob("*")
            if p.is_file()} == files  # intact, and no lock left behind
    assert [p.name for p in tmp_path.iterdir()] == ["mine"]


def test_an_empty_directory_is_filled_not_replaced(tmp_path):
    empty = tmp_path / "empty"
    empty.mkdir()
    assert main(["train", *TINY, "--out", str(empty), "--force"]) == 0
    assert (empty / ".tpo.run").is_file() and (empty / "eval.json").is_file()


def test_a_run_made_before_the_marker_counts_by_its_saved_model(finished, tmp_path):
    from tpo.experiments.runs import is_run

    run = copy_run(finished, tmp_path / "run")
    (run / ".tpo.run").unlink()
    assert is_run(run)  # by model/ and checkpoints/update-N/
    shutil.rmtree(run / "model")
    assert is_run(run)  # killed before its end: by its checkpoints
    assert main(["train", *TINY, "--out", str(run), "--force", "--seed", "1"]) == 0
    assert "seed = 1" in (run / "config.toml").read_text()
    assert (run / ".tpo.run").is_file() and (run / "model" / "model.json").is_file()
    assert [p.name for p in tmp_path.iterdir()] == ["run"]


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


@pytest.mark.parametrize("where", ["checkpoints/notes.txt", "model/notes.txt", "tb/notes.txt",
                                   "checkpoints/update-000003/notes.txt",
                                   "checkpoints/update-999999/config.toml", "model/link"])
def test_force_refuses_foreign_files_anywhere_in_the_run(finished, tmp_path, capsys, where):
    run = copy_run(finished, tmp_path / "run")
    target = run / where
    target.parent.mkdir(parents=True, exist_ok=True)
    if target.name == "link":
        target.symlink_to(tmp_path)
    else:
        target.write_text("precious")
    assert main(["train", *TINY, "--out", str(run), "--force"]) == 2
    err = capsys.readouterr().err
    assert "which tpo does not write in a run" in err, err
    assert target.is_symlink() or target.read_text() == "precious"


def test_a_move_that_fails_half_way_puts_everything_back(finished, tmp_path, monkeypatch,
                                                         capsys):
    import tpo.experiments.runs as runs

    run = copy_run(finished, tmp_path / "run")
    before = {p.relative_to(run): p.read_bytes() for p in run.rglob("*") if p.is_file()}
    real, moved = runs.os.replace, []

    def refuse_the_third(src, dst):
        moved.append(src)
        if len(moved) == 3:  # one file that cannot move (chattr +i)
            raise PermissionError(1, "Operation not permitted", str(src))
        return real(src, dst)

    monkeypatch.setattr(runs.os, "replace", refuse_the_third)
    assert main(["train", *TINY, "--out", str(run), "--force"]) == 2
    assert "Operation not permitted" in capsys.readouterr().err
    monkeypatch.undo()
    after = {p.relative_to(run): p.read_bytes() for p in run.rglob("*") if p.is_file()}
    assert after == before
    assert [p.name for p in tmp_path.iterdir()] == ["run"]


def test_a_run_stranded_by_a_killed_force_is_named_not_lost(finished, tmp_path, capsys):
    run = copy_run(finished, tmp_path / "run")
    holder = tmp_path / ".run.replaced.abc123"
    holder.mkdir()
    (run / "eval.json").rename(holder / "eval.json")  # as a kill mid-replacement leaves it
    for args in (["train", *TINY, "--out", str(run), "--force"],
                 ["train", "--resume", str(run), "--quiet"]):
        assert main(args) == 2
        assert f"an interrupted --force left the run it replaced in {holder}" in \
            capsys.readouterr().err
    assert (holder / "eval.json").exists()
