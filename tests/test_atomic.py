"""tpo.atomic: files written whole or not at all, with ordinary permissions."""

import os
import stat

import pytest

from tpo.atomic import UMASK, write_atomic


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
