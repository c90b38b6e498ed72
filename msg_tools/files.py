"""Paths read and written: regular files only on the way in, the permission bits of outputs on the way out.

:func:`regular_path` and :func:`open_regular` are the check every bag path
goes through before ``open()`` (a FIFO would block it, ``/dev/zero`` never
ends): :func:`belt_drive_ros.io.inputs.check_path`, with its refusal raised
as :class:`~msg_tools.errors.NotAFileError`.


``tempfile.mkstemp`` creates files readable by their owner only (0o600); an
output renamed from one would keep that. :func:`output_mode` gives the mode
a plain ``open(path, "w")`` would have left: that of the file being replaced,
else 0o666 less the process's umask.
"""

from __future__ import annotations

import os
import stat

from belt_drive_ros.io.inputs import InputError, check_path
from belt_drive_ros.io.inputs import open_regular as _open_regular

from .errors import NotAFileError

__all__ = ["open_regular", "output_mode", "regular_path"]


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
