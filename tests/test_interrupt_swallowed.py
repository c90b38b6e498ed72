"""A SIGINT/SIGTERM whose exception some code swallowed still interrupts the run.

Python raises a signal handler's exception in whatever the main thread runs at
that moment. One run in ~120 of ``belt-drive sim paper --duration 10000 --out
run.mcap`` SIGTERMed mid-run exited 0 with its output committed: the signal
had landed in the import of ``xml.etree.ElementTree``, whose C accelerator's
failed import its own ``except ImportError`` fallback took. ``io.atomic``
notes each signal; the commit points raise it again. Here the swallowing is
made on purpose, in-process and in a real ``belt-drive`` child.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from belt_drive_ros.io import atomic
from belt_drive_ros.io.atomic import Terminated, atomic_output, terminate_raises
from belt_drive_ros.io.bag_folder import bag_folder_kept

SIGNALS = [(signal.SIGTERM, Terminated), (signal.SIGINT, KeyboardInterrupt)]


def _swallowed(sig):
    """Receive ``sig`` and swallow its exception, as broad library code can."""
    try:
        signal.raise_signal(sig)
        raise AssertionError("the signal's exception was not raised")  # (the handler raises at once)
    except KeyboardInterrupt:
        pass


@pytest.mark.parametrize("sig, kind", SIGNALS)
def test_a_swallowed_signal_keeps_a_file_output_from_being_committed(tmp_path, sig, kind):
    out = tmp_path / "run.csv"
    out.write_text("old")
    with pytest.raises(kind) as caught, terminate_raises():
        with atomic_output(out, force=True, mode="w") as f:
            f.write("new, part")
            _swallowed(sig)
            f.write(" and the rest")
    assert type(caught.value) is kind
    assert out.read_text() == "old" and sorted(p.name for p in tmp_path.iterdir()) == ["run.csv"]
    assert atomic._received == [] and signal.getsignal(signal.SIGTERM) is signal.SIG_DFL
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


def test_a_swallowed_signal_keeps_a_new_bag_from_being_kept_and_puts_the_old_one_back(tmp_path):
    bag = tmp_path / "bag"
    bag.mkdir()
    (bag / "notes.txt").write_text("mine")
    (bag / "metadata.yaml").write_text("old")
    (bag / "bag_0.mcap").write_bytes(b"old")
    with pytest.raises(Terminated), terminate_raises():
        with bag_folder_kept(bag, force=True):
            (bag / "metadata.yaml").write_text("new")
            (bag / "bag_0.mcap").write_bytes(b"new")
            _swallowed(signal.SIGTERM)
    assert {p.name: p.read_bytes() for p in bag.iterdir()} == {"notes.txt": b"mine", "metadata.yaml": b"old",
                                                               "bag_0.mcap": b"old"}
    assert [p.name for p in tmp_path.iterdir()] == ["bag"]


def test_a_block_ending_normally_or_failing_after_a_swallowed_signal_ends_interrupted():
    with pytest.raises(Terminated), terminate_raises():
        _swallowed(signal.SIGTERM)
    with pytest.raises(KeyboardInterrupt) as caught, terminate_raises():
        _swallowed(signal.SIGINT)
        raise ImportError("what the swallowed interruption became")
    assert isinstance(caught.value.__cause__, ImportError)
    with terminate_raises():  # a block of its own: the earlier signals are not carried over
        pass
    assert atomic._received == []


# a real `belt-drive` program in which some code swallows a SIGTERM: at the third window of a streamed run,
# or while the summary of an in-memory run is made (before its output is written)
SWALLOWING = """
import signal, sys
from belt_drive_ros.io import run_writers
add, calls = run_writers.RunSummary.add, []
def swallowing_add(self, window):
    calls.append(1)
    if len(calls) == 3 or "--duration" not in sys.argv:
        try:
            signal.raise_signal(signal.SIGTERM)
        except KeyboardInterrupt:
            pass
    return add(self, window)
run_writers.RunSummary.add = swallowing_add
sys.argv = ["belt-drive"] + sys.argv[1:]
from belt_drive_ros.cli import main
sys.exit(main())
"""


@pytest.mark.parametrize("name, extra", [("run.mcap", ["--duration", "20000", "--force"]),
                                         ("bag", ["--duration", "20000", "--force"]), ("new-bag", ["--duration", "20000"]),
                                         ("run.csv", ["--force"]), ("bag", ["--force"]), ("new-bag", [])])
def test_a_program_whose_sigterm_was_swallowed_exits_143_with_its_outputs_removed(tmp_path, name, extra):
    """A streamed run (20,000 s: the signal at its third window) and an in-memory one (before its output
    is written); into a file and a bag folder replaced with --force (the old kept), and into a new bag
    folder (nothing left)."""
    out = tmp_path / name
    if name == "bag":
        out.mkdir()
        (out / "notes.txt").write_text("mine")
    elif name != "new-bag":
        out.write_bytes(b"old")
    cmd = [sys.executable, "-c", SWALLOWING, "sim", "paper", "--quiet", "--out", str(out)] + extra
    cmd += ["--bag-folder"] if "bag" in name else []
    run = subprocess.run(cmd, capture_output=True, text=True, cwd=tmp_path, timeout=600,
                         env={**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])})
    assert run.returncode == 143, run.stderr
    assert run.stderr.strip().splitlines() == ["belt-drive: interrupted by SIGTERM; unfinished outputs removed"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ([] if name == "new-bag" else [name])
    if name == "bag":
        assert sorted(p.name for p in out.iterdir()) == ["notes.txt"]
    elif name != "new-bag":
        assert out.read_bytes() == b"old"


# the same, while a streamed run's --plot overlay (a second run of the other model, as long as the first) begins:
# each of its windows after the signal is logged to the file named by the last argument
SWALLOWING_IN_OVERLAY = """
import signal, sys
from belt_drive_ros.commands import sim
from belt_drive_ros.io import run_writers
log, swallowed = sys.argv.pop(), []
overlay_method = sim._overlay_method
def swallowing_overlay_method(*args):
    try:
        signal.raise_signal(signal.SIGTERM)
    except KeyboardInterrupt:
        swallowed.append(1)
    return overlay_method(*args)
sim._overlay_method = swallowing_overlay_method
add = run_writers.Decimator.add
def logged_add(self, window):
    if swallowed:
        with open(log, "a") as f:
            f.write("window\\n")
    return add(self, window)
run_writers.Decimator.add = logged_add
sys.argv = ["belt-drive"] + sys.argv[1:]
from belt_drive_ros.cli import main
sys.exit(main())
"""


def test_a_sigterm_swallowed_as_the_plot_overlay_begins_stops_it_at_its_first_window(tmp_path):
    """The overlay ran to its end after the signal (a second run as long as the first: past the 90 s
    watchdog for a long one, which then ends the process with exit 1 instead of 143)."""
    log = tmp_path / "overlay.log"
    cmd = [sys.executable, "-c", SWALLOWING_IN_OVERLAY, "sim", "paper", "--quiet", "--duration", "20000",
           "--out", str(tmp_path / "run.mcap"), "--plot", str(tmp_path / "run.png"), "--plot-every", "1000", str(log)]
    run = subprocess.run(cmd, capture_output=True, text=True, cwd=tmp_path, timeout=600,
                         env={**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])})
    assert run.returncode == 143, run.stderr
    assert log.read_text().splitlines() == ["window"]  # (the window at which it stopped)
    assert not (tmp_path / "run.png").exists()


def test_a_program_without_stderr_still_gets_the_interruption_at_the_first_signal(monkeypatch):
    """A program started with its stderr closed has ``sys.stderr`` None, which faulthandler refuses: arming
    the watchdog raised that RuntimeError in place of the interruption, so ``except KeyboardInterrupt``
    (an interrupted campaign's keeping of its parts) missed it and ``except Exception`` took it (a sweep's
    batch recorded as failed: "sys.stderr is None"). The stacks go to descriptor 2 then."""
    monkeypatch.setattr(sys, "stderr", None)
    caught = []
    with pytest.raises(Terminated), terminate_raises(atomic.CLEANUP_LIMIT):
        try:
            signal.raise_signal(signal.SIGTERM)
        except KeyboardInterrupt as exc:
            caught.append(exc)
            raise
    assert [type(e) for e in caught] == [Terminated]


def test_a_signal_while_the_old_bag_is_set_aside_puts_every_file_of_it_back(tmp_path, monkeypatch):
    """SIGTERM (as Terminated) landing between the moves of the old bag's files into the hidden folder: they
    were moved before the block's try, so the files moved so far stayed in ``.bag.*.old`` and the folder kept a
    bag without them (its metadata.yaml naming a file that was gone), though the run said it was interrupted.
    Now every file is back in the folder and no hidden folder is left, as for a signal during the run."""
    from belt_drive_ros.io import bag_folder

    bag = tmp_path / "bag"
    bag.mkdir()
    old = {"metadata.yaml": b"old", "bag_0.mcap": b"old0", "bag_1.mcap": b"old1", "notes.txt": b"mine"}
    for name, data in old.items():
        (bag / name).write_bytes(data)
    replace, calls = os.replace, []

    def interrupted_replace(src, dst):
        calls.append(src)
        if len(calls) == 2:  # (the second file of the old bag: one is in the hidden folder already)
            raise Terminated(signal.SIGTERM)
        return replace(src, dst)

    monkeypatch.setattr(bag_folder.os, "replace", interrupted_replace)
    with pytest.raises(Terminated):
        with bag_folder_kept(bag, force=True):
            pytest.fail("the block ran")
    monkeypatch.setattr(bag_folder.os, "replace", replace)
    assert {p.name: p.read_bytes() for p in bag.iterdir()} == old
    assert [p.name for p in tmp_path.iterdir()] == ["bag"]
