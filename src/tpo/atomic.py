"""Files and directories written whole or not at all: a kill never leaves a
half-written one."""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


UMASK = _umask()  # read once: os.umask can only be read by setting it


def write_atomic(path: str | Path, data: str | bytes, replace: bool = True) -> None:
    """Write ``data`` to ``path`` through a synced temporary file and a rename (with
    the permissions a plain ``open`` would give, not the temporary file's 0600).
    With ``replace`` false an existing ``path`` is never replaced, even one made
    meanwhile (:class:`FileExistsError`): the file is linked in, not renamed."""
    path = Path(path)
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    except OSError as err:  # name the file asked for, not the temporary one
        raise OSError(err.errno, err.strerror, str(path)) from None
    try:
        os.fchmod(fd, 0o666 & ~UMASK)
        with os.fdopen(fd, "wb") as fh:
            fh.write(data.encode() if isinstance(data, str) else data)
            fh.flush()
            os.fsync(fh.fileno())
        if replace:
            os.replace(tmp, path)
        else:
            os.link(tmp, path)
    except OSError as err:
        raise OSError(err.errno, err.strerror, str(path)) from None
    finally:
        Path(tmp).unlink(missing_ok=True)


def write_dir_atomic(path: str | Path, files: dict[str, str | bytes],
                     overwrite: bool = False) -> Path:
    """Write the directory ``path`` holding ``files`` (name -> contents) through a
    synced temporary directory and renames: a kill leaves the old directory, the
    new one, or (between the two renames, with the old one kept aside) none,
    never a half-written one. An existing ``path`` is replaced only
    with ``overwrite`` (else :class:`FileExistsError`)."""
    path = Path(path)
    if path.exists() and not overwrite:
        raise FileExistsError(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", dir=path.parent))
    try:
        tmp.chmod(0o777 & ~UMASK)  # a plain mkdir's permissions, not mkdtemp's 0700
        for name, data in files.items():
            with open(tmp / name, "wb") as fh:
                fh.write(data.encode() if isinstance(data, str) else data)
                fh.flush()
                os.fsync(fh.fileno())
        if path.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{path.name}.old.", dir=path.parent))
            os.replace(path, old / path.name)
            os.replace(tmp, path)
            shutil.rmtree(old)
        else:
            os.replace(tmp, path)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return path
