"""Output files written whole or not at all.

Every output of the tool (JSON, CSV, PNG/PDF/SVG, ``.rrd``) is written to a temporary file
in the destination's folder and moved onto the destination with :func:`os.replace` only
once it is complete: a full disk, an error or Ctrl-C part-way leaves the destination as it
was (absent, or the previous complete file) and no temporary file behind.

A write error is re-raised as :class:`OSError` whose ``filename`` is the destination (not
the temporary file), so the one-line message names the file the user asked for.
"""

from __future__ import annotations

import contextlib
import errno
import os
import secrets
import stat
from collections.abc import Iterator
from pathlib import Path

#: the temporary file's name: ``.NAME.<random>.part`` beside the destination
_TMP_SUFFIX = ".part"


def _is_regular_target(path: Path) -> bool:
    """Whether ``path`` may be replaced by a renamed file (absent, or a regular file)."""
    try:
        return not path.exists() or path.is_file()
    except OSError:
        return True


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success it replaces ``path``.

    Use: ``with atomic_path(out) as tmp: write(tmp)``. The folder of ``path`` is created when
    missing. Leaving the block by any exception (``KeyboardInterrupt`` included) removes the
    temporary file and leaves ``path`` untouched.

    A destination that is not a regular file (``/dev/null``, ``/dev/full``, a FIFO) cannot be
    replaced by a rename: it is written in place, and a failing write still raises.

    Raises:
        OSError: the folder cannot be created or the file cannot be written; ``filename``
            is ``path``.
    """
    path = Path(path)
    if not _is_regular_target(path):
        try:
            yield path
        except OSError as exc:
            raise OSError(exc.errno, exc.strerror or str(exc), str(path)) from None
        return
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = _create_beside(path)
    except OSError as exc:
        raise OSError(exc.errno, exc.strerror or str(exc), str(path)) from None
    try:
        yield tmp
        os.replace(tmp, path)
    except OSError as exc:
        _unlink(tmp)
        raise OSError(exc.errno, exc.strerror or str(exc), str(path)) from None
    except BaseException:
        _unlink(tmp)
        raise


def _create_beside(path: Path) -> Path:
    """Create an empty ``.NAME.<random>.part`` beside ``path`` with the mode a plain write gives:
    the existing file's, else 0o666 less the umask (``tempfile.mkstemp`` would give 0o600)."""
    try:
        mode = stat.S_IMODE(path.stat().st_mode)
    except OSError:
        mode = None
    for _ in range(100):
        tmp = path.with_name(f".{path.name}.{secrets.token_hex(4)}{_TMP_SUFFIX}")
        try:
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        except FileExistsError:
            continue
        try:
            if mode is not None:
                os.fchmod(fd, mode)
        finally:
            os.close(fd)
        return tmp
    raise FileExistsError(errno.EEXIST, "no free temporary file name", str(path))


def _unlink(p: Path) -> None:
    with contextlib.suppress(OSError):
        p.unlink()


def write_bytes(path: str | Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically (see :func:`atomic_path`); returns ``path``.

    The data is flushed to the disk (``fsync``) before the rename, so a full disk shows up
    here as ``OSError(ENOSPC)`` and not as a silently short file later.
    """
    with atomic_path(path) as tmp, open(tmp, "wb") as fh:
        fh.write(data)
        fh.flush()
        if tmp != Path(path):
            os.fsync(fh.fileno())
    return Path(path)


def write_text(path: str | Path, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically; returns ``path``."""
    return write_bytes(path, text.encode("utf-8"))
