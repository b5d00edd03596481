"""One writer per directory: an advisory lock that tpo's commands hold on a run,
sweep or reproduction directory for as long as they work in it.

The lock is ``fcntl.flock`` on ``DIR/.tpo.lock``, which also records the holder's
pid. The kernel drops it when the holder exits, however it exits, so a killed
run never leaves a stale lock behind. The lock is opened without following a
symlink, and only a regular file with no other name is written to.
"""

from __future__ import annotations

import errno
import fcntl
import os
import stat
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from tpo.errors import TPOError

LOCK_FILE = ".tpo.lock"


class LockError(TPOError):
    """Another process works in the directory."""


@contextmanager
def exclusive(directory: str | Path, create: bool = False) -> Iterator[Path]:
    """Hold ``directory``'s lock for the ``with`` block, or raise :class:`LockError`
    naming the holder's pid at once. ``create`` makes the directory (and its
    parents) if it is missing. If the block fails, a lock file it made is removed,
    and so is a directory it made that is then empty."""
    directory = Path(directory)
    if directory.exists() and not directory.is_dir():
        raise LockError(f"{directory} is a file, not a directory")
    made = False
    if create and not directory.exists():
        try:
            directory.mkdir(parents=True)
            made = True
        except FileExistsError:  # another process made it first: its lock decides
            pass
    path = directory / LOCK_FILE
    existed = path.exists()
    fd = _open_lock(path)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.read(fd, 32).decode(errors="replace").strip() or "unknown"
            raise LockError(f"{directory} is in use by another tpo process (pid {holder}); "
                            "wait for it to finish or stop it") from None
        os.ftruncate(fd, 0)
        os.write(fd, str(os.getpid()).encode())
        try:
            yield directory
        except BaseException:  # leave nothing behind in a directory tpo was refused
            if not existed:
                path.unlink(missing_ok=True)
            if made and not any(directory.iterdir()):
                directory.rmdir()
            raise
    finally:
        os.close(fd)


def _open_lock(path: Path) -> int:
    """Open (or create) the lock file ``path`` without following a symlink; raise
    :class:`LockError` if it is a symlink, or not a regular file of its own (a
    hard link or a special file), which writing the pid would change."""
    try:
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW, 0o666)
    except OSError as err:
        if err.errno == errno.ELOOP:
            raise LockError(f"{path} is a symlink; tpo writes through no link in a "
                            "directory it works in: remove it") from None
        raise
    info = os.fstat(fd)
    if not stat.S_ISREG(info.st_mode) or info.st_nlink != 1:
        os.close(fd)
        raise LockError(f"{path} is not a lock file of its own (a hard link or a special "
                        "file); remove it")
    return fd
