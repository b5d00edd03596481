"""tpo.atomic: files written whole or not at all, with ordinary permissions."""

import os
import stat

import pytest

from tpo.atomic import UMASK, write_atomic, write_dir_atomic


def test_an_atomic_file_has_the_permissions_of_a_plain_one(tmp_path):
    write_atomic(tmp_path / "a.txt", "x")
    (tmp_path / "b.txt").write_text("x")
    mode = stat.S_IMODE(os.stat(tmp_path / "a.txt").st_mode)
    assert mode == stat.S_IMODE(os.stat(tmp_path / "b.txt").st_mode) == 0o666 & ~UMASK


def test_a_failed_write_leaves_neither_the_file_nor_a_temporary(tmp_path):
    with pytest.raises(TypeError):
        write_atomic(tmp_path / "a.txt", 3)  # neither str nor bytes
    assert list(tmp_path.iterdir()) == []


def test_a_rewrite_replaces_the_whole_file(tmp_path):
    write_atomic(tmp_path / "a.txt", "a long first version")
    write_atomic(tmp_path / "a.txt", b"short")
    assert (tmp_path / "a.txt").read_text() == "short"
    assert [p.name for p in tmp_path.iterdir()] == ["a.txt"]


def test_a_directory_is_written_whole_and_replaced_only_when_asked(tmp_path):
    path = tmp_path / "model"
    write_dir_atomic(path, {"a.json": "{}", "b.bin": b"\x00\x01"})
    assert sorted(p.name for p in path.iterdir()) == ["a.json", "b.bin"]
    assert stat.S_IMODE(os.stat(path).st_mode) == 0o777 & ~UMASK
    with pytest.raises(FileExistsError):
        write_dir_atomic(path, {"c": "x"})
    write_dir_atomic(path, {"c": "x"}, overwrite=True)
    assert [p.name for p in path.iterdir()] == ["c"]
    with pytest.raises(TypeError):
        write_dir_atomic(path, {"d": 3}, overwrite=True)  # neither str nor bytes
    assert [p.name for p in tmp_path.iterdir()] == ["model"]  # no temporary left behind
    assert [p.name for p in path.iterdir()] == ["c"]  # the old directory is kept


def test_a_write_that_must_not_replace_leaves_a_file_made_meanwhile(tmp_path):
    path = tmp_path / "f"
    write_atomic(path, "new", replace=False)
    assert path.read_text() == "new"
    with pytest.raises(FileExistsError):
        write_atomic(path, "newer", replace=False)
    assert path.read_text() == "new"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f"]  # no temporary left


def test_an_error_names_the_file_asked_for_not_the_temporary(tmp_path):
    with pytest.raises(FileNotFoundError) as err:
        write_atomic(tmp_path / "missing" / "f", "x")
    assert err.value.filename == str(tmp_path / "missing" / "f")
