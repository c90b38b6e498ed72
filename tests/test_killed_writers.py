"""What a writer killed outright (SIGKILL) leaves is settled by the next write of the same output, and two runs
never write one bag folder at once; refusals of an existing output read as one plain sentence."""

from __future__ import annotations

import os
import subprocess
import sys
import warnings

import pytest

from belt_drive_ros.cli import main
from belt_drive_ros.io.atomic import atomic_output
from msg_tools import Ros2McapWriter
from msg_tools.bagdir import Ros2BagWriter
from msg_tools.errors import OverwriteError

RUN = ["sim", "paper", "--duration", "0.01", "--quiet"]

#: a process that starts writing ``argv[1]`` through atomic_output and is killed outright halfway
KILLED_WRITER = """
import os, signal, sys
from belt_drive_ros.io.atomic import atomic_output
with atomic_output(sys.argv[1], mode="w") as f:
    f.write("half a run\\n")
    f.flush()
    os.kill(os.getpid(), signal.SIGKILL)
"""

#: a process that holds a bag folder's lock until its stdin closes (``kill``: killed while holding it)
LOCK_HOLDER = """
import os, signal, sys
from belt_drive_ros.io.bag_folder import bag_folder_lock
with bag_folder_lock(sys.argv[1]):
    print("held", flush=True)
    if sys.argv[2] == "kill":
        os.kill(os.getpid(), signal.SIGKILL)
    sys.stdin.read()
"""


def _parts(folder):
    return sorted(p.name for p in folder.iterdir() if p.name.endswith(".part"))


def _child(code, *args, **kwargs):
    return subprocess.Popen([sys.executable, "-c", code, *map(str, args)], text=True, **kwargs)


# ------------------------------------------------------------------ .NAME.*.part of a killed writer
def test_the_part_file_of_a_killed_writer_is_removed_by_the_next_run_which_says_so(tmp_path, capsys):
    out = tmp_path / "run.csv"
    killed = _child(KILLED_WRITER, out)
    assert killed.wait(timeout=120) == -9
    left = _parts(tmp_path)
    assert len(left) == 1 and not out.exists()  # what SIGKILL leaves: no run.csv, its temporary file
    assert main(RUN + ["--out", str(out)]) == 0
    assert _parts(tmp_path) == [] and out.read_text().startswith("time,phi_M,")
    assert capsys.readouterr().err == (f"belt-drive: warning: --out {out}: removed 1 unfinished temporary file(s) of "
                                       f"a run killed while writing it ({left[0]})\n")


def test_a_live_writers_part_file_is_left_alone(tmp_path):
    from msg_tools.files import settle_parts

    out = tmp_path / "run.csv"
    stale = tmp_path / ".run.csv.stale.part"  # no writer holds it
    with atomic_output(out, force=True, mode="w") as f:
        f.write("outer\n")
        (live,) = _parts(tmp_path)
        stale.write_text("half")
        assert settle_parts(out) == [stale.name] and _parts(tmp_path) == [live]
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # nothing to settle, nothing said
            with atomic_output(out, force=True, mode="w") as g:  # a second write of the same path meanwhile
                g.write("inner\n")
        assert _parts(tmp_path) == [live] and out.read_text() == "inner\n"
    assert _parts(tmp_path) == [] and out.read_text() == "outer\n"  # the live one was finished, not taken


def test_msg_tools_settles_a_killed_writers_part_file_too(tmp_path, capsys):
    from msg_tools.cli import _atomic

    stale = tmp_path / ".out.csv.x1y2.part"
    stale.write_text("half")
    with _atomic(str(tmp_path / "out.csv"), False, "w") as f:
        f.write("a\n")
    assert _parts(tmp_path) == [] and (tmp_path / "out.csv").read_text() == "a\n"
    err = capsys.readouterr().err
    assert err == f"msg-tools: warning: {tmp_path / 'out.csv'}: removed 1 unfinished temporary file(s) of a run " \
                  f"killed while writing it ({stale.name})\n"


# ------------------------------------------------------------------ one run at a time into a bag folder
def test_a_second_run_into_a_bag_folder_being_written_names_the_holder_and_exits_1(tmp_path, capsys):
    folder = tmp_path / "bag"
    holder = _child(LOCK_HOLDER, folder, "hold", stdin=subprocess.PIPE, stdout=subprocess.PIPE)
    try:
        assert holder.stdout.readline() == "held\n"
        assert main(RUN + ["--out", str(folder), "--bag-folder", "--force"]) == 1
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith(f"belt-drive: error: --out {folder}: another run "
                                                   f"(pid {holder.pid}) is writing this bag folder"), err
        assert not folder.exists()  # nothing settled, moved or written
    finally:
        holder.stdin.close()
        assert holder.wait(timeout=60) == 0
    assert main(RUN + ["--out", str(folder), "--bag-folder"]) == 0  # released: the next run writes
    assert (folder / "metadata.yaml").is_file() and sorted(p.name for p in tmp_path.iterdir()) == ["bag"]


def test_the_lock_of_a_killed_run_is_taken_over(tmp_path, capsys):
    folder = tmp_path / "bag"
    holder = _child(LOCK_HOLDER, folder, "kill", stdout=subprocess.PIPE)
    assert holder.stdout.readline() == "held\n" and holder.wait(timeout=60) == -9
    assert (tmp_path / ".bag.lock").read_text() == f"{holder.pid}\n"  # left, held by nobody
    assert main(RUN + ["--out", str(folder), "--bag-folder"]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bag"]
    capsys.readouterr()


@pytest.mark.parametrize("planted", ["symlink", "fifo"])
def test_a_link_or_fifo_planted_as_the_lock_file_is_refused_not_followed(tmp_path, capsys, planted):
    """The lock file is opened without following a link: a link planted at ``.NAME.lock`` had the run truncate
    the file it points to and write its pid there (and unlink only the link); a FIFO is no lock file either."""
    folder, lock = tmp_path / "bag", tmp_path / ".bag.lock"
    victim = tmp_path / "precious.txt"
    victim.write_text("keep me\n")
    os.symlink(victim, lock) if planted == "symlink" else os.mkfifo(lock)
    assert main(RUN + ["--out", str(folder), "--bag-folder"]) == 1
    out, err = capsys.readouterr()
    why = ("cannot make its lock file {lock}: a symbolic link is there (never followed: remove it)" if planted == "symlink"
           else "its lock file {lock} is not a regular file (a FIFO or socket: remove it)")
    assert err == f"belt-drive: error: --out {folder}: " + why.format(lock=lock) + "\n"
    assert out == "" and victim.read_text() == "keep me\n" and not folder.exists() and os.path.lexists(lock)


def test_still_at_is_the_file_at_the_path_now_never_through_a_link(tmp_path):
    """``io.inputs.still_at``: the one same-file check of the .part files' (msg_tools.files) and the bag folder's
    locks."""
    from belt_drive_ros.io.inputs import still_at

    path, link, other = tmp_path / "f", tmp_path / "link", tmp_path / "g"
    path.write_text("a")
    other.write_text("b")
    os.symlink(path, link)
    fd = os.open(path, os.O_RDONLY)
    try:
        assert still_at(fd, path) and still_at(fd, str(path))
        assert not still_at(fd, link) and not still_at(fd, other)
        os.replace(other, path)  # another file at the path now
        assert not still_at(fd, path)
        path.unlink()
        assert not still_at(fd, path)
    finally:
        os.close(fd)


def test_an_existing_bag_is_refused_before_the_run_without_force(tmp_path, capsys):
    folder = tmp_path / "bag"
    assert main(RUN + ["--out", str(folder), "--bag-folder"]) == 0
    capsys.readouterr()
    assert main(RUN + ["--out", str(folder), "--bag-folder"]) == 2
    out, err = capsys.readouterr()
    assert err == f"belt-drive: error: --out {folder} exists and holds a bag; pass --force to overwrite it\n"
    assert out == ""  # refused before the run: no summary


@pytest.mark.parametrize("entry", [".mcap", "take.mcap", "metadata.yaml", "old.mcap/", "notes.txt", "take.MCAP", None])
def test_a_bag_folder_holds_a_bag_by_the_writers_own_rule(tmp_path, capsys, monkeypatch, entry):
    """``io.holds_bag`` (what ``sim --bag-folder`` refuses before its run, and how a scene argument is told from a
    recording) answers as the bag writer's refusal does, for every folder content; a folder the writer would refuse
    is refused before the run (the sim command had its own test, which missed an entry named ``.mcap``)."""
    from belt_drive_ros.core import simulate as simulate_module
    from belt_drive_ros.io import holds_bag, is_recording

    folder = tmp_path / "bag"
    folder.mkdir()
    if entry is not None:
        (folder / entry.rstrip("/")).mkdir() if entry.endswith("/") else (folder / entry).write_bytes(b"precious")
    try:
        Ros2BagWriter(folder).finish()
        refused = False
    except OverwriteError:
        refused = True
    for f in folder.iterdir():  # (what the accepted writer wrote goes: the folder as it was)
        if f.name in ("bag_0.mcap", "metadata.yaml") and f.name != entry:
            f.unlink()
    assert holds_bag(folder) == refused == is_recording(folder), entry
    if not refused:
        return

    def run_not_allowed(*_args, **_kwargs):
        raise AssertionError("the run started before the refusal")

    monkeypatch.setattr(simulate_module, "simulate", run_not_allowed)
    assert main(RUN + ["--out", str(folder), "--bag-folder"]) == 2
    out, err = capsys.readouterr()
    assert err == f"belt-drive: error: --out {folder} exists and holds a bag; pass --force to overwrite it\n"
    assert out == "" and sorted(p.name for p in folder.iterdir()) == [entry.rstrip("/")]


# ------------------------------------------------------------------ the refusal's words
def test_overwrite_refusals_are_one_plain_sentence(tmp_path):
    path = tmp_path / "run.mcap"
    path.write_bytes(b"precious")
    with pytest.raises(OverwriteError) as info:
        Ros2McapWriter(path)
    assert str(info.value) == f"{path} exists; pass --force to overwrite it"
    folder = tmp_path / "bag"
    folder.mkdir()
    (folder / "bag_0.mcap").write_bytes(b"precious")
    with pytest.raises(OverwriteError) as info:
        Ros2BagWriter(folder)
    assert str(info.value) == f"{folder} exists and holds a bag; pass --force to overwrite it"
