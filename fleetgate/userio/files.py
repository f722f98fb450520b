"""Files a user asked for appear whole or not at all.

:func:`atomic_open` writes into a temporary file in the target's folder and, once everything
is written and synced, renames it over the target: an interrupted or failed write (Ctrl-C, a
full disk) leaves the previous file as it was and no temporary file behind. A target that is
no regular file (``/dev/stdout``, ``/dev/full``, a FIFO) is written directly: nothing can be
renamed over it. Every failure is a :class:`CannotWrite` with a one-line reason.
"""

from __future__ import annotations

import contextlib
import os
import stat
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any, Literal

from fleetgate.userio.exits import UsageError


class CannotWrite(UsageError):
    """A file a user asked for cannot be written: ``cannot write [WHAT] PATH: reason`` (exit
    2; ``what`` says which output, e.g. "the trace")."""

    def __init__(self, path: str | os.PathLike[str], exc: OSError, what: str = "") -> None:
        super().__init__(f"cannot write {what + ' ' if what else ''}{os.fspath(path)}: "
                         f"{describe(exc)}")


def describe(exc: OSError) -> str:
    """An OSError in words, without the ``[Errno N]`` prefix or a repeated file name."""
    if exc.errno == 20:  # ENOTDIR: a file stands where the path needs a folder
        return "a file stands where a folder is needed on this path"
    return exc.strerror or str(exc) or type(exc).__name__


def _special(path: Path) -> bool:
    try:
        return not stat.S_ISREG(path.stat().st_mode)
    except OSError:
        return False


@contextlib.contextmanager
def atomic_open(path: str | os.PathLike[str], mode: Literal["w", "wb"] = "w",
                newline: str | None = None, what: str = "") -> Iterator[IO[Any]]:
    """Open ``path`` for writing; it is replaced only when the block ends without an exception.

    Raises :class:`CannotWrite` for any OSError (a missing folder, a file where a folder is
    expected, no space, no permission), whether opening, writing or renaming; ``what`` names
    the output in its message.
    """
    target = Path(path)
    encoding = None if "b" in mode else "utf-8"
    if _special(target):
        try:
            with open(target, mode, encoding=encoding, newline=newline) as direct:
                yield direct
        except OSError as exc:
            raise CannotWrite(target, exc, what) from None
        return
    try:
        fd, tmp = tempfile.mkstemp(dir=target.parent, prefix=f".{target.name}.", suffix=".tmp")
    except OSError as exc:
        raise CannotWrite(target, exc, what) from None
    try:
        with os.fdopen(fd, mode, encoding=encoding, newline=newline) as f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, target)
    except OSError as exc:
        _discard(tmp)
        raise CannotWrite(target, exc, what) from None
    except BaseException:
        _discard(tmp)
        raise


def _discard(tmp: str) -> None:
    with contextlib.suppress(OSError):
        os.unlink(tmp)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def write_text(path: str | os.PathLike[str], text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically (see :func:`atomic_open`)."""
    with atomic_open(path) as f:
        f.write(text)


def write_bytes(path: str | os.PathLike[str], data: bytes) -> None:
    """Write ``data`` to ``path`` atomically (see :func:`atomic_open`)."""
    with atomic_open(path, "wb") as f:
        f.write(data)


def check_writable(path: str | os.PathLike[str], what: str = "") -> None:
    """CannotWrite now if ``path`` could not be written later (a missing folder, a file
    where a folder is expected, no permission), without touching a file already there: a
    command checks its outputs before a long run, and writes them atomically after it."""
    target = Path(path)
    if target.is_dir():
        raise UsageError(f"cannot write {what + ' ' if what else ''}{target}: it is a folder")
    if _special(target):
        return
    try:
        fd, tmp = tempfile.mkstemp(dir=target.parent, prefix=f".{target.name}.", suffix=".tmp")
    except OSError as exc:
        raise CannotWrite(target, exc, what) from None
    os.close(fd)
    _discard(tmp)


def make_folder(path: str | os.PathLike[str]) -> Path:
    """Create the folder ``path`` (and its parents) if missing; CannotWrite with one line if
    it cannot be (a file stands there, no permission)."""
    folder = Path(path)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise UsageError(f"cannot write into {folder}: it is a file, not a folder") from None
    except OSError as exc:
        raise CannotWrite(folder, exc) from None
    return folder
