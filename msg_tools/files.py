"""Paths read and written: regular files only on the way in, the permission bits of outputs on the way out.

:func:`regular_path` and :func:`open_regular` are the check every bag path
goes through before ``open()`` (a FIFO would block it, ``/dev/zero`` never
ends): :func:`belt_drive_ros.io.inputs.check_path`, with its refusal raised
as :class:`~msg_tools.errors.NotAFileError`.


``tempfile.mkstemp`` creates files readable by their owner only (0o600); an
output renamed from one would keep that. :func:`output_mode` gives the mode
a plain ``open(path, "w")`` would have left: that of the file being replaced,
else 0o666 less the process's umask.

An output is written whole or not at all through a temporary ``.NAME.<random>.part``
beside it (:func:`new_part`), renamed onto it once written. Its writer holds an
exclusive ``flock`` on it until then; the kernel drops that lock with the
process, so a ``.part`` file nobody holds is what a writer killed outright
(SIGKILL, power loss) left, and the next write of the same output removes it
(:func:`settle_parts`); one a live writer holds is left alone.
"""

from __future__ import annotations

import fcntl
import os
import stat
import tempfile

from belt_drive_ros.io.inputs import InputError, check_path, still_at
from belt_drive_ros.io.inputs import open_regular as _open_regular

from .errors import NotAFileError

__all__ = ["PART", "new_part", "open_regular", "output_mode", "regular_path", "settle_parts"]

#: the suffix of an output's temporary file (``.NAME.<random>.part`` in its folder)
PART = ".part"


def regular_path(path: str | os.PathLike, folder: bool = False, what: str = "bag") -> os.stat_result:
    """``os.stat`` of ``path`` if it is a regular file (or, with ``folder``, a directory), else
    :class:`NotAFileError` naming what it is (FIFO, device, socket, a name the OS refuses)."""
    try:
        return check_path(path, what, folder=folder)
    except InputError as exc:
        raise NotAFileError(str(exc)) from None


def open_regular(path: str | os.PathLike, what: str = "bag") -> int:
    """A read-only descriptor of the regular file ``path`` (never blocks on a FIFO swapped in);
    refusals as :class:`NotAFileError`."""
    try:
        return _open_regular(path, what)
    except InputError as exc:
        raise NotAFileError(str(exc)) from None


def output_mode(path: str | os.PathLike) -> int:
    """Permission bits for a new ``path``: those of the file it replaces, else 0o666 less the umask."""
    try:
        return stat.S_IMODE(os.stat(path).st_mode)
    except OSError:
        mask = os.umask(0)
        os.umask(mask)
        return 0o666 & ~mask


def _folder(path: str | os.PathLike) -> str:
    return os.path.dirname(os.fspath(path)) or "."


def new_part(path: str | os.PathLike) -> tuple[int, str]:
    """A new temporary file for ``path`` (``.NAME.<random>.part`` in its folder) and its name, locked by its
    writer (``flock``, exclusive) for as long as a descriptor of it is open (a ``dup`` of ``fd`` keeps the lock
    past the file's close, up to the rename). Made again if :func:`settle_parts` of another process took it in
    the instant before the lock."""
    folder, prefix = _folder(path), f".{os.path.basename(os.fspath(path))}."
    while True:
        fd, name = tempfile.mkstemp(dir=folder, prefix=prefix, suffix=PART)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            if still_at(fd, name):
                return fd, name
        except BlockingIOError:
            pass
        except BaseException:
            os.close(fd)
            raise
        os.close(fd)


def settle_parts(path: str | os.PathLike) -> list[str]:
    """Remove the temporary files of ``path`` (``.NAME.*.part``) that no writer holds: what writers killed
    outright left (see the module docstring). Returns their names (sorted; [] if none); never raises."""
    folder, prefix = _folder(path), f".{os.path.basename(os.fspath(path))}."
    removed = []
    try:
        entries = [e for e in os.scandir(folder) if e.name.startswith(prefix) and e.name.endswith(PART)
                   and e.is_file(follow_symlinks=False)]
    except OSError:
        return []
    for e in entries:
        try:
            fd = os.open(e.path, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC)
        except OSError:
            continue
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)  # held: its writer is alive (or settling it now)
            if still_at(fd, e.path):
                os.unlink(e.path)
                removed.append(e.name)
        except OSError:
            pass
        finally:
            os.close(fd)
    return sorted(removed)
