"""Reading a file the user names, bounded: a regular file only, and no more bytes than a limit; writing one
atomically, and checking before the work that it can be written."""

from __future__ import annotations

import os
import stat
from contextlib import suppress
from pathlib import Path

from ilcpmac.core.errors import IlcpmacError

__all__ = ["atomic_write", "check_writable", "read_bounded"]


def read_bounded(path: Path, max_bytes: int, error: type[IlcpmacError]) -> bytes:
    """The bytes of the regular file ``path``, at most ``max_bytes``; anything else raises ``error`` naming it.

    A folder, FIFO or device is refused: the file is opened without blocking and checked to be a regular file
    before a byte is read; a file whose size is beyond ``max_bytes`` is refused before a byte is read, and one
    that grows meanwhile is read no further than ``max_bytes + 1``.
    """
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
    except FileNotFoundError:
        raise error(f"{path}: no such file") from None
    except (OSError, ValueError) as e:
        raise error(f"{path}: cannot read ({getattr(e, 'strerror', None) or e})") from None
    try:
        status = os.fstat(fd)
        if not stat.S_ISREG(status.st_mode):
            raise error(f"{path}: not a regular file (a folder, FIFO or device is refused)")
        if status.st_size > max_bytes:
            raise error(f"{path}: more than {max_bytes} bytes (refused)")
        with open(fd, "rb", closefd=False) as f:
            raw = f.read(max_bytes + 1)
    except OSError as e:
        raise error(f"{path}: cannot read ({e.strerror or e})") from None
    finally:
        os.close(fd)
    if len(raw) > max_bytes:
        raise error(f"{path}: more than {max_bytes} bytes (refused)")
    return raw


def _temporary(path: Path) -> Path:
    """The temporary file `atomic_write` writes ``path`` through: PATH.tmp, beside it."""
    return path.with_name(path.name + ".tmp")


def atomic_write(path: Path, data: bytes | str, durable: bool = True) -> None:
    """Write via a temporary file and rename, so a reader never sees half a file.

    ``durable`` also fsyncs before the rename, so the file survives a power cut. On any failure (a full disk,
    a quota, a read-only place, an interrupt) the temporary file is removed; an `OSError` is raised again
    with ``path`` as its file name (the one the CLI names), its errno and reason kept.
    """
    tmp = _temporary(path)
    try:
        with open(tmp, "wb") as f:
            f.write(data.encode() if isinstance(data, str) else data)
            if durable:
                f.flush()
                os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException as e:
        with suppress(OSError):
            tmp.unlink(missing_ok=True)
        if isinstance(e, OSError):
            raise OSError(e.errno, e.strerror or str(e), str(path)) from None
        raise


def check_writable(path: Path, error: type[IlcpmacError]) -> None:
    """Check, before the work that makes its contents, that `atomic_write` can write ``path``; else raise
    ``error`` naming it.

    Its folder is made, and its temporary file created and removed there; a folder, FIFO or device at ``path``
    is refused (a rename would replace it).
    """
    if path.exists() and not path.is_file():
        raise error(f"{path}: not a regular file (a folder, FIFO or device is refused)")
    tmp = _temporary(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with open(tmp, "wb"):
            pass
        tmp.unlink()
    except OSError as e:
        raise error(f"{path}: cannot be written ({e.strerror or e})") from None
