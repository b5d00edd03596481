"""No symlink is followed out of a run directory (issue 62, item 1): a lock, or a
file or folder tpo writes in a run, that is a link is refused in one line before
anything is written, and what the link names is left byte for byte as it was."""

import os
import shutil
from pathlib import Path

import pytest

from tpo.cli.main import main
from tpo.locking import LOCK_FILE

TRAIN = ["--map", "small", "--dag", "A>G", "--slack", "0", "--steps", str(2 * 2048 * 12),
         "--episodes", "2", "--quiet"]  # checkpoints after updates 16 and 24
COMMANDS = {
    "train --resume": ["train", "--resume", "{run}", "--quiet", "--episodes", "2"],
    "eval": ["eval", "{run}", "--episodes", "2"],
    "export": ["export", "{run}", "--format", "npz", "--out", "{tmp}/policy.npz"],
    "render": ["render", "{run}"],
}
PRECIOUS = b"a user's file\n"


@pytest.fixture(scope="module")
def finished(tmp_path_factory) -> Path:
    """A finished small run (trained once for the module)."""
    out = tmp_path_factory.mktemp("runs") / "done"
    assert main(["train", *TRAIN, "--out", str(out)]) == 0
    return out


def copy_run(finished: Path, dst: Path, cut_back: bool) -> Path:
    """A copy of ``finished``; ``cut_back``: as a kill after update 16 leaves it, so
    that ``--resume`` has updates to train and checkpoints to write."""
    shutil.copytree(finished, dst)
    if cut_back:
        for done in (dst / "model", dst / "checkpoints" / "update-000024"):
            shutil.rmtree(done)
        (dst / "eval.json").unlink()
    return dst


def tree(root: Path) -> dict[Path, bytes | str | None]:
    """Every entry under ``root`` (its lock aside), following no link: a file's bytes,
    a link's target, None for a folder."""
    found = {}
    for parent, folders, files in os.walk(root):
        for name in folders + files:
            path = Path(parent) / name
            if name != LOCK_FILE or path.parent != root:
                found[path.relative_to(root)] = os.readlink(path) if path.is_symlink() \
                    else path.read_bytes() if path.is_file() else None
    return found


def command_line(name: str, run: Path, tmp_path: Path) -> list[str]:
    return [a.replace("{run}", str(run)).replace("{tmp}", str(tmp_path))
            for a in COMMANDS[name]]


@pytest.mark.parametrize("kind", ["symlink", "dangling symlink", "hard link"])
@pytest.mark.parametrize("command", COMMANDS)
def test_a_lock_that_is_a_link_is_refused_and_what_it_names_is_untouched(
        finished, tmp_path, capsys, command, kind):
    run = copy_run(finished, tmp_path / "run", cut_back=command == "train --resume")
    lock, target = run / LOCK_FILE, tmp_path / "mine.txt"
    lock.unlink()
    if kind != "dangling symlink":
        target.write_bytes(PRECIOUS)
    os.link(target, lock) if kind == "hard link" else lock.symlink_to(target)
    before = tree(run)
    assert main(command_line(command, run, tmp_path)) == 2
    reason = ("is not a lock file of its own (a hard link or a special file); remove it"
              if kind == "hard link" else
              "is a symlink; tpo writes through no link in a directory it works in: "
              "remove it")
    assert capsys.readouterr().err == f"tpo: error: {lock} {reason}\n"
    assert tree(run) == before
    if kind == "dangling symlink":
        assert os.readlink(lock) == str(target) and not target.exists()  # nothing made
    else:
        assert target.read_bytes() == PRECIOUS
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        ["run", *(["mine.txt"] if kind != "dangling symlink" else [])])  # no export


@pytest.mark.parametrize("name", ["checkpoints", "tb", "metrics.csv", "model",
                                  "checkpoints/update-000016"])
def test_resume_refuses_a_link_where_it_writes_and_writes_nothing(finished, tmp_path, capsys,
                                                                  name):
    run = copy_run(finished, tmp_path / "run", cut_back=True)
    link, elsewhere = run / name, tmp_path / "elsewhere"
    elsewhere.mkdir()
    if link.exists():  # the run's own files, moved out of it
        link.rename(elsewhere / link.name)
    else:  # a user's folder where the final model would go
        (elsewhere / link.name).mkdir()
        (elsewhere / link.name / "notes.txt").write_bytes(PRECIOUS)
    link.symlink_to(elsewhere / link.name, target_is_directory=link.name != "metrics.csv")
    before, outside = tree(run), tree(elsewhere)
    assert main(command_line("train --resume", run, tmp_path)) == 2
    assert capsys.readouterr().err == (
        f"tpo: error: {link} is a symlink; tpo writes through no link in a run directory: "
        "replace it with the file or folder itself\n")
    assert tree(elsewhere) == outside
    assert tree(run) == before


@pytest.mark.parametrize("name", ["policy.png", "policy.pdf"])
def test_render_refuses_a_figure_of_the_run_that_is_a_link(finished, tmp_path, capsys, name):
    run = copy_run(finished, tmp_path / "run", cut_back=False)
    target = tmp_path / f"mine{Path(name).suffix}"
    target.write_bytes(PRECIOUS)
    (run / name).symlink_to(target)
    before = tree(run)
    assert main(command_line("render", run, tmp_path)) == 2
    assert capsys.readouterr().err == (
        f"tpo: error: {run / name} is a symlink; tpo writes through no link in a run "
        "directory: replace it with the file or folder itself\n")
    assert target.read_bytes() == PRECIOUS
    assert tree(run) == before
