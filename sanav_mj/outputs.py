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


class StreamedFile:
    """A text output written piece by piece (a campaign's CSV rows as they arrive) and put in
    place whole at the end.

    :meth:`write` appends to a temporary file beside ``path`` (UTF-8, no newline
    translation, for :mod:`csv`); :meth:`commit` syncs it and renames it onto ``path``;
    :meth:`discard` removes it. A write that fails (a full disk) does not raise at once: the
    temporary file is removed, later writes are ignored and :meth:`commit` raises the error
    (``filename`` = ``path``), so the caller's work and its other outputs go on. A destination
    that is not a regular file (``/dev/full``) is written in place, as in :func:`atomic_path`.
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.error: OSError | None = None
        self._tmp: Path | None = None
        self._fh = None
        try:
            if _is_regular_target(self.path):
                self.path.parent.mkdir(parents=True, exist_ok=True)
                self._tmp = _create_beside(self.path)
                self._fh = open(self._tmp, "w", newline="", encoding="utf-8")  # noqa: SIM115 - closed by commit/discard
            else:
                self._fh = open(self.path, "w", newline="", encoding="utf-8")  # noqa: SIM115
        except OSError as exc:
            self._fail(exc)

    def _fail(self, exc: OSError) -> None:
        if self.error is None:
            self.error = OSError(exc.errno, exc.strerror or str(exc), str(self.path))
        self._close()
        if self._tmp is not None:
            _unlink(self._tmp)

    def _close(self) -> None:
        fh, self._fh = self._fh, None
        if fh is not None:
            with contextlib.suppress(OSError):
                fh.close()

    def write(self, text: str) -> None:
        """Append ``text`` (a failure is kept for :meth:`commit`)."""
        if self._fh is None:
            return
        try:
            self._fh.write(text)
        except OSError as exc:
            self._fail(exc)

    def commit(self) -> Path:
        """Flush, sync and rename the file onto ``path``; returns ``path``.

        Raises:
            OSError: a write, the flush or the rename failed (``filename`` is ``path``); the
                destination is then as it was.
        """
        if self._fh is not None:
            try:
                self._fh.flush()
                if self._tmp is not None:
                    os.fsync(self._fh.fileno())
                self._fh.close()
                self._fh = None
                if self._tmp is not None:
                    os.replace(self._tmp, self.path)
            except OSError as exc:
                self._fail(exc)
        if self.error is not None:
            raise self.error
        return self.path

    def discard(self) -> None:
        """Remove the temporary file (the destination stays as it was)."""
        self._close()
        if self._tmp is not None:
            _unlink(self._tmp)


class OutputFailures:
    """Write several outputs, each whole or not at all, and go on past one that fails.

    ``attempt(path, write)`` calls ``write()`` and keeps an :class:`OSError` it raises;
    :meth:`check` then raises the first one, naming its file (and how many more failed).
    """

    def __init__(self) -> None:
        self.errors: list[OSError] = []

    def attempt(self, path: str | Path, write) -> None:
        """Call ``write()``; an :class:`OSError` is kept (named ``path`` when it names no file)."""
        try:
            write()
        except OSError as exc:
            self.errors.append(exc if exc.filename else OSError(exc.errno, exc.strerror or str(exc), str(path)))

    def check(self) -> None:
        """Raise the first kept error, if any.

        Raises:
            OSError: ``filename`` the first output not written; the message adds how many
                other outputs were not written.
        """
        if not self.errors:
            return
        first = self.errors[0]
        more = f" (and {len(self.errors) - 1} more output(s) not written)" if len(self.errors) > 1 else ""
        raise OSError(first.errno, (first.strerror or str(first)) + more, first.filename)
