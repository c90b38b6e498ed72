"""Errors and warnings raised by :mod:`msg_tools`.

Every error derives from :class:`MsgToolsError` and from the built-in exception
a caller would naturally catch (``FileNotFoundError``, ``ValueError``,
``KeyError``, ``FileExistsError``, ``OSError``). Each message is one line and
names the file, topic or type that is wrong, so the command line can print it
as ``msg-tools: error: <message>`` without a traceback.
"""

from __future__ import annotations

import os
from typing import Iterable, Optional, Union

PathLike = Union[str, "os.PathLike[str]"]


def _one_line(text: str) -> str:
    """Collapse ``text`` onto a single line (newlines become ``"; "``)."""
    return "; ".join(part.strip() for part in str(text).splitlines() if part.strip())


class MsgToolsError(Exception):
    """Base class of every error raised by :mod:`msg_tools`."""

    def __init__(self, message: str):
        self.message = _one_line(message)
        super().__init__(self.message)

    def __str__(self) -> str:
        return self.message


class BagNotFoundError(MsgToolsError, FileNotFoundError):
    """The bag file does not exist (or is a directory without an MCAP file)."""

    def __init__(self, path: PathLike, detail: str = "no such file"):
        self.filename = os.fspath(path)
        MsgToolsError.__init__(self, f"bag not found: {self.filename} ({detail})")


class NotAFileError(MsgToolsError, ValueError):
    """The path cannot be read as a bag: a FIFO, a device, a socket, or a name the OS refuses."""


class CorruptBagError(MsgToolsError, ValueError):
    """The input is not an MCAP file, or a record in it cannot be decoded."""


class DecodeError(CorruptBagError):
    """A message payload cannot be decoded with its declared type and encoding."""


class TopicNotFoundError(MsgToolsError, KeyError):
    """A requested topic is not in the bag; the message lists the topics that are."""

    def __init__(self, topic: str, path: PathLike, available: Iterable[str]):
        self.topic = topic
        self.available = sorted(available)
        listing = ", ".join(self.available) if self.available else "none"
        MsgToolsError.__init__(
            self, f"topic {topic!r} not found in {os.fspath(path)} (topics: {listing})"
        )


class UnknownMessageTypeError(MsgToolsError, KeyError):
    """A message type has no built-in ``.msg`` definition and none was registered."""

    def __init__(self, type_name: str, known: Iterable[str]):
        self.type_name = type_name
        self.known = sorted(known)
        MsgToolsError.__init__(
            self,
            f"unknown message type {type_name!r}; known types: {', '.join(self.known)} "
            "(register others with Ros2McapWriter.register_type)",
        )


class OverwriteError(MsgToolsError, FileExistsError):
    """The output file (or bag folder) exists and overwriting was not requested: ``--force`` on the command line,
    ``force=True`` in Python."""

    def __init__(self, path: PathLike):
        self.filename = os.fspath(path)
        what = "exists and holds a bag" if os.path.isdir(self.filename) else "exists"
        MsgToolsError.__init__(self, f"{self.filename} {what}; pass --force to overwrite it")


class WriteError(MsgToolsError, OSError):
    """Writing the output failed (disk full, permission denied, closed stream, ...).

    ``errno`` and ``strerror`` are copied from the underlying ``OSError`` so a
    caller can tell ``ENOSPC`` from ``EACCES``. The writer stops writing after
    the first error; the caller decides whether the program goes on.
    """

    def __init__(self, path: PathLike, cause: Union[BaseException, str], action: str = "write"):
        self.filename = os.fspath(path) if path is not None else "<stream>"
        if isinstance(cause, OSError):
            reason = cause.strerror or str(cause) or type(cause).__name__
            err_no: Optional[int] = cause.errno
        else:
            reason = str(cause)
            err_no = None
        MsgToolsError.__init__(self, f"cannot {action} {self.filename}: {reason}")
        self.errno = err_no
        self.strerror = reason


class RecoveredBagWarning(UserWarning):
    """The bag was not finished by its writer; only complete records were read."""
