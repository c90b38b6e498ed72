"""Outputs that appear whole or not at all.

:func:`check_output` decides up front (before a run) whether a path may be
written: an existing regular file only with ``force``, never a device, FIFO
or directory (``--out /dev/full`` would otherwise "succeed" into nothing, and
replacing a device node by a file would be worse), and the parent folder
must exist. :func:`atomic_output` then writes to a temporary file in the
same folder and renames it onto the path only when everything was written
and flushed to disk: a full disk, an I/O error or an interrupted run leaves
no partial file (and the temporary one is removed).

A run killed outright (SIGKILL, power loss) cannot remove its temporary
file: the next write of the same path does, and says so in a warning
(:func:`msg_tools.files.settle_parts`: a temporary file is locked by its
writer while it lives, so a live run's is never taken).

An interrupted run is such a failure too: SIGINT raises
:class:`KeyboardInterrupt` by Python's default, and :func:`terminate_raises`
makes SIGTERM (which would end the process without running any ``finally``)
raise :class:`Terminated`, so the temporary file of an output in progress is
removed before the process exits (``belt-drive sim`` then exits 128 + the
signal number, as a shell reports a process ended by that signal).

That removal is bounded in a program (``belt-drive``): the first SIGINT or
SIGTERM arms :mod:`faulthandler`'s watchdog, a thread outside the interpreter
that needs no lock of Python's. Should the removal not end within
:data:`CLEANUP_LIMIT` seconds (a cleanup stuck on a lock), it prints every
thread's stack to stderr and ends the process with exit 1: an interrupted run
never hangs, and the stacks say where it stuck. (Not ``belt-drive sweep``: a
campaign acts on a signal at the end of the batch running and closes its
cluster itself, and a process ended by the watchdog would orphan its workers.)
"""

from __future__ import annotations

import contextlib
import faulthandler
import os
import signal
import stat
import sys
import threading
import tempfile
import warnings
from pathlib import Path
from typing import IO, Iterator

from ..core.errors import BeltDriveError, OutputError

__all__ = ["OutputRefused", "Terminated", "atomic_output", "check_output", "interruption_handled", "raise_if_interrupted",
           "terminate_raises", "write_output"]


class OutputRefused(BeltDriveError, ValueError):
    """An output path is refused before anything runs (exists without --force, not a regular file, no folder)."""


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised in the main thread by :func:`terminate_raises` (``signum`` is its number)."""

    def __init__(self, signum: int = signal.SIGTERM):
        super().__init__(f"terminated by {signal.Signals(signum).name}")
        self.signum = int(signum)


#: seconds a program interrupted by SIGINT or SIGTERM may spend removing its unfinished outputs (under a
#: second here; tens of seconds on a machine at load 15) before :func:`terminate_raises`' watchdog ends it
CLEANUP_LIMIT = 90.0


#: the SIGINT/SIGTERM numbers the running :func:`terminate_raises` block received, in order
_received: list[int] = []
#: the outputs the last :func:`terminate_raises` block committed (:func:`committed_outputs`); None outside a block
_committed: list[str] | None = None
#: the list the open block notes its commits in (None: no block open, nothing noted)
_noting: list[str] | None = None


def note_committed(path) -> None:
    """Note that output ``path`` is complete and in place (a file renamed onto its name, a bag folder kept), so an
    interruption after it says it is kept (:func:`committed_outputs`). Outside a :func:`terminate_raises` block:
    nothing."""
    if _noting is not None:
        _noting.append(str(path))


def committed_outputs() -> list[str]:
    """The outputs the last :func:`terminate_raises` block committed before it was left (a run interrupted after
    writing its ``--out`` while its ``--plot`` or summary was still being made keeps that output whole), in order."""
    return list(_committed or ())


def _interruption(signum: int) -> KeyboardInterrupt:
    return KeyboardInterrupt() if signum == signal.SIGINT else Terminated(signum)


def raise_if_interrupted() -> None:
    """Raise again the first SIGINT/SIGTERM the running :func:`terminate_raises` block received, if any.

    A signal's exception is raised in whatever the main thread runs when it
    arrives, and code that catches broadly can swallow it: seen here in one
    run of ~120, a SIGTERM landing in ``import xml.etree.ElementTree``, whose
    C accelerator's import of ``pyexpat`` lost it (the import falls back to
    the pure-Python module and succeeds, as it does when an import hook
    raises :class:`KeyboardInterrupt` at ``pyexpat``), and the run went on to
    commit its output and exit 0 as if never interrupted. Each commit point
    calls this first: :func:`atomic_output` before its rename,
    :func:`~belt_drive_ros.io.bag_folder.bag_folder_kept` before it keeps the
    new bag, a streamed ``belt-drive sim`` after each window, and the block's
    own end.
    """
    if _received:
        raise _interruption(_received[0])


def interruption_handled() -> None:
    """Say that the running :func:`terminate_raises` block's interruption was caught and acted on (an
    interrupted campaign keeps its parts and says how to resume): the commit points and the block's end no
    longer raise it again. Code that catches :class:`KeyboardInterrupt` to go on calls this."""
    _received.clear()


@contextlib.contextmanager
def terminate_raises(cleanup_limit: float | None = None) -> Iterator[None]:
    """While the block runs, SIGTERM raises :class:`Terminated` in the main thread.

    Without it SIGTERM ends the process on the spot and an
    :func:`atomic_output` in progress leaves its ``.NAME.*.part`` file
    behind; with it the ``finally`` clauses run (the temporary file is
    removed, the old file kept). SIGINT, where it raises
    :class:`KeyboardInterrupt` (Python's default), still does. Either is
    also noted: a signal whose exception some code swallowed is raised again
    at the next commit point (:func:`raise_if_interrupted`), and a block
    that ends with another exception after one ends with the interruption
    instead (the other as its cause). The previous handlers are restored on
    exit; outside the main thread (where Python cannot set handlers) nothing
    changes. For commands without a ROS context only (rclpy installs its own
    handlers).

    ``cleanup_limit`` [s] (a program's own, never an in-process caller's: it
    ends the process): the first signal arms
    :func:`faulthandler.dump_traceback_later` with it. If the block has not
    been left that many seconds later, every thread's stack goes to stderr
    and the process ends with exit 1; leaving the block disarms it.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def on_signal(signum, frame):
        _received.append(int(signum))
        if cleanup_limit is not None and len(_received) == 1:
            # (descriptor 2 where sys.stderr is None, a program started with it closed: faulthandler's refusal of
            # None was raised here in place of the interruption)
            faulthandler.dump_traceback_later(cleanup_limit, exit=True, file=2 if sys.stderr is None else sys.stderr)
        raise _interruption(signum)

    global _committed, _noting
    _received.clear()
    _committed = _noting = []
    previous = {signal.SIGTERM: signal.signal(signal.SIGTERM, on_signal)}
    if signal.getsignal(signal.SIGINT) is signal.default_int_handler:  # (an ignored SIGINT stays ignored)
        previous[signal.SIGINT] = signal.signal(signal.SIGINT, on_signal)
    try:
        yield
        raise_if_interrupted()
    except BaseException as exc:
        if _received and not isinstance(exc, KeyboardInterrupt):  # what the swallowed interruption became
            raise _interruption(_received[0]) from exc
        raise
    finally:
        _noting = None  # (what it committed stays readable: committed_outputs)
        if cleanup_limit is not None:
            faulthandler.cancel_dump_traceback_later()
        try:  # (signal.signal raises a signal that arrived just before: the other handler is restored all the same)
            signal.signal(signal.SIGTERM, previous.pop(signal.SIGTERM))
        finally:
            for sig, handler in previous.items():
                signal.signal(sig, handler)
            _received.clear()


def check_output(path: str | os.PathLike, force: bool = False, what: str = "output") -> Path:
    """``path`` as a :class:`~pathlib.Path` if it may be written, else :class:`OutputRefused`.

    Refused: an existing path that is not a regular file (device, FIFO,
    directory, socket), an existing file without ``force``, a missing folder.
    """
    path = Path(path)
    try:
        st = os.stat(path)
    except FileNotFoundError:
        st = None
    except OSError as exc:
        raise OutputRefused(f"{what} {path}: {exc.strerror or exc}") from None
    if st is not None:
        if not stat.S_ISREG(st.st_mode):
            kind = "a directory" if stat.S_ISDIR(st.st_mode) else "not a regular file (device, FIFO or socket)"
            raise OutputRefused(f"{what} {path}: {kind}; outputs are written to regular files only")
        if not force:
            raise OutputRefused(f"{what} {path} exists; pass --force to overwrite it")
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.is_dir():
        raise OutputRefused(f"{what} {path}: folder {parent} does not exist")
    check_writable_folder(parent, f"{what} {path}", path.name)
    return path


def check_writable_folder(folder: Path, named: str, stem: str) -> None:
    """Refuse (:class:`OutputRefused`, naming ``named``) a folder nothing can be written into: a temporary file is
    made there and removed (a folder of /proc, read-only or full of inodes: refused before anything runs)."""
    try:
        fd, probe = tempfile.mkstemp(dir=folder, prefix=f".{stem}.", suffix=".part")
    except OSError as exc:
        raise OutputRefused(f"{named}: cannot write into folder {folder}: {exc.strerror or exc}") from None
    os.close(fd)
    with contextlib.suppress(FileNotFoundError):  # (another run's settle_parts may have taken it: it is unlocked)
        os.unlink(probe)


def _temporary(path: Path, mode: str) -> tuple[IO, str]:
    """A new temporary file next to ``path`` opened in ``mode``, and its name.

    ``mkstemp`` creates it readable by its owner only; it gets the
    permissions ``path`` would have had if written directly
    (:func:`msg_tools.files.output_mode`) before anything is written. It is
    locked while a descriptor of it is open (:func:`msg_tools.files.new_part`).
    """
    from msg_tools.files import new_part, output_mode  # on use: `belt-drive sim` without --out loads no msg_tools

    fd, name = new_part(path)
    try:
        os.fchmod(fd, output_mode(path))
        if "b" in mode:
            return os.fdopen(fd, mode), name
        return os.fdopen(fd, mode, encoding="utf-8", newline=""), name
    except BaseException:
        os.close(fd)
        os.unlink(name)
        raise


@contextlib.contextmanager
def atomic_output(path: str | os.PathLike, force: bool = False, mode: str = "wb", what: str = "output") -> Iterator[IO]:
    """Context manager yielding a file that becomes ``path`` only if the block succeeds.

    The data goes to a temporary file in ``path``'s folder, is flushed and
    ``fsync``-ed, and is renamed onto ``path`` (atomic on POSIX). On any
    exception the temporary file is removed and ``path`` is untouched; an
    :class:`OSError` (disk full, I/O error) becomes :class:`OutputError`
    naming the output.

    Parameters
    ----------
    path : output path (checked by :func:`check_output`).
    force : replace an existing regular file.
    mode : ``"wb"`` (binary) or ``"w"`` (UTF-8 text, ``\\n`` line ends).
    """
    path = check_output(path, force, what)
    _settle(path, what)
    try:
        handle, name = _temporary(path, mode)
        lock = os.dup(handle.fileno())  # the temporary file stays locked past its close, up to the rename
    except OSError as exc:
        raise OutputError(f"{what} {path}: {exc.strerror or exc}; nothing written") from None
    done = False
    try:
        with handle:
            yield handle
            handle.flush()
            os.fsync(handle.fileno())
        raise_if_interrupted()  # (a signal whose exception was swallowed: the output is not committed)
        if not force and os.path.lexists(path):
            raise OutputRefused(f"{what} {path} appeared while writing; pass --force to overwrite it")
        os.replace(name, path)
        done = True
        note_committed(path)
    except OSError as exc:
        if isinstance(exc, OutputRefused):
            raise
        reason = os.strerror(exc.errno) if isinstance(exc.errno, int) and exc.errno > 0 else str(exc)
        raise OutputError(f"{what} {path}: {reason}; nothing written") from None
    finally:
        if not done:
            with contextlib.suppress(OSError):
                os.unlink(name)
        os.close(lock)


def _settle(path: Path, what: str) -> None:
    """Remove what writers of ``path`` killed outright left (:func:`msg_tools.files.settle_parts`), saying so in a
    warning (``belt-drive: warning: ...`` on the command line)."""
    from msg_tools.files import settle_parts

    removed = settle_parts(path)
    if removed:
        warnings.warn(f"{what} {path}: removed {len(removed)} unfinished temporary file(s) of a run killed while "
                      f"writing it ({', '.join(removed)})", stacklevel=4)


def write_output(path: str | os.PathLike, data: str | bytes, force: bool = False, what: str = "output") -> Path:
    """Write ``data`` (text as UTF-8, or bytes) to ``path`` through :func:`atomic_output`; return the path."""
    with atomic_output(path, force, "w" if isinstance(data, str) else "wb", what) as f:
        f.write(data)
    return Path(path)
