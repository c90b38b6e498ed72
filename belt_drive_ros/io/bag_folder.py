"""A bag folder written with ``--force`` (``belt-drive sim --bag-folder``): the old bag kept until the new one is whole,
and what a run killed outright left of it.

:func:`bag_folder_kept` moves the bag already in the folder into a hidden sibling ``.NAME.<random>.old`` while the
new one is written: removed when the write succeeds, moved back when it fails or is interrupted. A process killed
outright (SIGKILL, power loss) runs neither, and leaves the old bag in that sibling; the next run into the folder
settles it first (:func:`settle_set_aside`): a bag is whole once its ``metadata.yaml`` is written (rosbag2's layout:
:class:`msg_tools.bagdir.Ros2BagWriter` writes it last, in one rename), so

* the folder without a whole bag (the killed run's unfinished files, or none): those files are removed and the old
  bag is moved back;
* the folder with a whole bag (the killed run finished it, not its clean-up): the old bag is removed, as that run
  would have removed it.

One run writes a bag folder at a time (:func:`bag_folder_lock`): a second run into it while the first holds its
lock file (``.NAME.lock`` beside the folder, the holder's pid in it) is refused, naming that pid, before it settles,
moves or writes anything.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import os
import shutil
import stat
import tempfile
from pathlib import Path

from ..core.errors import OutputError
from .atomic import note_committed, raise_if_interrupted
from .inputs import still_at

__all__ = ["BagFolderBusy", "bag_files_in", "bag_folder_kept", "bag_folder_lock", "remove_bag_folder", "set_aside",
           "settle_set_aside"]

#: the name of what a bag writer leaves last in its folder, once every file is closed
METADATA = "metadata.yaml"
#: the suffix of a set-aside bag's hidden sibling folder (``.NAME.<random>.old``)
OLD = ".old"
#: the suffix of the lock file a run writing a bag folder holds beside it (``.NAME.lock``)
LOCK = ".lock"


class BagFolderBusy(OutputError):
    """Another run holds the bag folder's lock (:func:`bag_folder_lock`): nothing was written (exit 1)."""


@contextlib.contextmanager
def bag_folder_lock(folder, what: str = "--out"):
    """Hold ``folder``'s lock while the block writes its bag: an exclusive ``flock`` on ``.NAME.lock`` beside the
    folder, the holder's pid written in it, the file removed on exit. Held elsewhere: :class:`BagFolderBusy` naming
    that pid. The kernel drops a lock with its process, so a run killed outright leaves a file nobody holds, which
    the next run takes over. The lock file is opened without following a symbolic link (a link planted there would
    have this run truncate the file it points to) and must be a regular file. Messages start with ``what`` (the
    option or parameter that named the folder) and the folder."""
    folder = Path(folder)
    named = f"{what} {folder}" if what else f"{folder}"
    path = folder.absolute().parent / f".{folder.name}{LOCK}"
    while True:
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC | os.O_NOFOLLOW | os.O_NONBLOCK, 0o644)
        except OSError as exc:
            why = "a symbolic link is there (never followed: remove it)" if exc.errno == errno.ELOOP else exc.strerror
            raise OutputError(f"{named}: cannot make its lock file {path}: {why or exc}") from None
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            os.close(fd)
            raise OutputError(f"{named}: its lock file {path} is not a regular file (a FIFO or socket: "
                              "remove it)")
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _holder(fd)
            os.close(fd)
            raise BagFolderBusy(f"{named}: another run ({holder}) is writing this bag folder (it holds "
                                f"{path}); nothing written: wait for it to end or write elsewhere") from None
        except BaseException:
            os.close(fd)
            raise
        if still_at(fd, path):  # the file locked is still the one at the path (its last holder removes it when done)
            break
        os.close(fd)
    try:
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        yield
    finally:
        with contextlib.suppress(OSError):
            os.unlink(path)  # (while held: a run waiting on the old file retries on a new one)
        os.close(fd)


def _holder(fd: int) -> str:
    """``pid N`` as the lock file's holder wrote it (``pid unknown`` before it has)."""
    try:
        text = os.pread(fd, 32, 0).decode("ascii", "replace").strip()
    except OSError:
        text = ""
    return f"pid {text}" if text.isdigit() else "pid unknown"


@contextlib.contextmanager
def bag_folder_kept(folder, force: bool):
    """While a bag is written into ``folder`` with ``force``: the bag already there (its :func:`bag_files_in`) moved
    aside into a hidden sibling folder (``.NAME.*.old``), removed once the block succeeds and moved back if it fails or
    is interrupted (after the writer removed its own files), as a file output keeps the old file until the new one
    is whole. A process killed outright leaves the old bag in the hidden folder (:func:`settle_set_aside`)."""
    folder = Path(folder)
    files = bag_files_in(folder) if force else []
    if not files:
        try:
            yield
            raise_if_interrupted()  # (a signal whose exception was swallowed: the new bag is not kept)
        except BaseException:
            if force:  # (nothing of ours to keep: what the new bag left goes)
                remove_bag_folder(folder)
            raise
        note_committed(folder)
        return
    backup = Path(tempfile.mkdtemp(dir=folder.absolute().parent, prefix=f".{folder.name}.", suffix=OLD))
    try:
        for f in files:
            os.replace(f, backup / f.name)
    except BaseException:  # (a signal between the moves: the files moved so far go back)
        _put_back(backup, folder)
        raise
    try:
        yield
        raise_if_interrupted()
    except BaseException:
        remove_bag_folder(folder)  # (what the new bag left, if anything)
        _put_back(backup, folder)
        raise
    note_committed(folder)
    shutil.rmtree(backup, ignore_errors=True)


def set_aside(folder) -> list[Path]:
    """The hidden sibling folders (``.NAME.*.old``) holding a bag :func:`bag_folder_kept` set aside for ``folder``,
    oldest first (by when the bag was moved in)."""
    folder = Path(folder)
    prefix = f".{folder.name}."
    try:
        entries = [e for e in os.scandir(folder.absolute().parent)
                   if e.name.startswith(prefix) and e.name.endswith(OLD) and e.is_dir(follow_symlinks=False)]
    except OSError:
        return []
    found = []
    for e in entries:
        try:
            found.append((e.stat(follow_symlinks=False).st_mtime_ns, e.name, Path(e.path)))
        except OSError:
            pass
    return [path for *_, path in sorted(found)]


def settle_set_aside(folder) -> list[str]:
    """Settle the bags a run killed outright left set aside for ``folder`` (see the module docstring), oldest first:
    each moved back when ``folder`` holds no whole bag (its unfinished files removed first), else removed. Returns a
    line per bag saying what was done ([] if none was found)."""
    folder = Path(folder)
    done = []
    for old in set_aside(folder):
        if (folder / METADATA).is_file():
            shutil.rmtree(old, ignore_errors=True)
            done.append(f"--out {folder}: removed {old.name}, the bag it held before a run that was killed after "
                        f"writing this one (whole: its {METADATA} is written) had set aside")
            continue
        unfinished = bag_files_in(folder)
        remove_bag_folder(folder)
        _put_back(old, folder)
        done.append(f"--out {folder}: put back the bag a run killed while replacing it had set aside in {old.name}"
                    + (f" (the {len(unfinished)} unfinished files it wrote, without {METADATA}, removed)"
                       if unfinished else ""))
    return done


def _put_back(backup: Path, folder: Path) -> None:
    """The set-aside bag's files back into ``folder`` (made if missing), then its hidden folder removed."""
    folder.mkdir(exist_ok=True)
    for f in backup.iterdir():
        os.replace(f, folder / f.name)
    backup.rmdir()


def bag_files_in(folder) -> list[Path]:
    """What a bag writer puts in ``folder``: ``metadata.yaml`` and ``NAME_<i>.mcap`` (none if it is no folder)."""
    folder = Path(folder)
    name = folder.resolve().name
    found = []
    try:
        for f in folder.iterdir():
            stem = f.name[: -len(".mcap")] if f.name.endswith(".mcap") else ""
            if f.name == METADATA or (stem.startswith(name + "_") and stem[len(name) + 1:].isdigit()):
                found.append(f)
    except OSError:
        pass
    return found


def remove_bag_folder(folder) -> None:
    """Remove what a bag writer puts in ``folder`` (``metadata.yaml``, ``NAME_<i>.mcap``), then the
    folder if nothing else is left in it; other files stay. Never raises."""
    try:
        for f in bag_files_in(folder):
            f.unlink()
        Path(folder).rmdir()
    except OSError:
        pass
