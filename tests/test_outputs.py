"""Output safety (issue 13): formats by extension, --force for every output, no partial files, one-line errors."""

from __future__ import annotations

import contextlib
import errno
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from belt_drive_ros.cli import main
from belt_drive_ros.core.errors import OutputError
from belt_drive_ros.io import atomic
from belt_drive_ros.io.atomic import OutputRefused, atomic_output

RUN = ["sim", "paper", "--duration", "0.2", "--quiet"]


def _run(capsys, argv, code):
    got = main(argv)
    captured = capsys.readouterr()
    assert got == code, captured.err
    assert "Traceback" not in captured.err
    if code:
        lines = captured.err.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("belt-drive: error: "), captured.err
        return lines[0]
    return captured.out


def _leftovers(folder):
    return sorted(p.name for p in folder.iterdir() if p.name.endswith(".part"))


# ------------------------------------------------------------------ formats
def test_format_follows_the_extension_case_insensitively(tmp_path, capsys):
    _run(capsys, RUN + ["--out", str(tmp_path / "x.MCAP")], 0)
    assert (tmp_path / "x.MCAP").read_bytes()[:5] == b"\x89MCAP"
    _run(capsys, RUN + ["--out", str(tmp_path / "x.Csv")], 0)
    assert (tmp_path / "x.Csv").read_text().startswith("time,phi_M,")


@pytest.mark.parametrize("name", ["x.txt", "x", "x.mcap.bak"])
def test_unknown_extension_is_refused_before_the_run(tmp_path, capsys, name):
    line = _run(capsys, RUN + ["--out", str(tmp_path / name)], 2)
    assert "unknown format" in line and ".csv or .mcap" in line
    assert list(tmp_path.iterdir()) == []


def test_plot_must_be_png(tmp_path, capsys):
    line = _run(capsys, RUN + ["--plot", str(tmp_path / "x.csv")], 2)
    assert "--plot" in line and ".png" in line
    assert list(tmp_path.iterdir()) == []


# ------------------------------------------------------------------ --force
def test_force_governs_the_plot(tmp_path, capsys):
    keep = tmp_path / "keep.png"
    keep.write_bytes(b"precious")
    line = _run(capsys, RUN + ["--plot", str(keep)], 2)
    assert "exists; pass --force" in line and keep.read_bytes() == b"precious"
    _run(capsys, RUN + ["--plot", str(keep), "--force"], 0)
    assert keep.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_existing_out_is_refused_before_the_run(tmp_path, capsys):
    keep = tmp_path / "keep.csv"
    keep.write_text("keep me\n")
    line = _run(capsys, RUN + ["--out", str(keep)], 2)
    assert "exists; pass --force" in line and keep.read_text() == "keep me\n"


@pytest.mark.parametrize("option", ["--out", "--plot"])
def test_device_outputs_are_refused(capsys, option):
    target = "/dev/full.png" if option == "--plot" and os.path.exists("/dev/full.png") else "/dev/full"
    line = _run(capsys, RUN + [option, target, "--force"], 2)
    assert "/dev/full" in line
    assert "regular file" in line or ".png" in line


def test_plot_device_with_png_name_is_refused(tmp_path, capsys):
    fifo = tmp_path / "pipe.png"
    os.mkfifo(fifo)
    line = _run(capsys, RUN + ["--plot", str(fifo), "--force"], 2)
    assert "not a regular file" in line


def test_missing_folder(tmp_path, capsys):
    line = _run(capsys, RUN + ["--out", str(tmp_path / "no" / "x.csv")], 2)
    assert "does not exist" in line


# ------------------------------------------------------------------ full disk
class _FullDisk:
    """A temporary file whose disk fills after ``room`` bytes (ENOSPC), like a real full file system."""

    def __init__(self, handle, room):
        self._handle, self._room = handle, room

    def write(self, data):
        self._room -= len(data)
        if self._room < 0:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return self._handle.write(data)

    def __getattr__(self, name):
        return getattr(self._handle, name)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self._handle.close()


@pytest.fixture
def full_disk(monkeypatch):
    real = atomic._temporary

    def temporary(path, mode):
        handle, name = real(path, mode)
        return _FullDisk(handle, 3000), name

    monkeypatch.setattr(atomic, "_temporary", temporary)


@pytest.mark.parametrize("option, name", [("--out", "run.csv"), ("--out", "run.mcap"), ("--plot", "run.png")])
def test_full_disk_fails_in_one_line_and_leaves_nothing(tmp_path, capsys, full_disk, option, name):
    line = _run(capsys, RUN + [option, str(tmp_path / name)], 1)
    assert name in line and "No space left on device" in line and "nothing written" in line
    assert list(tmp_path.iterdir()) == []


def test_full_disk_keeps_the_old_file_with_force(tmp_path, capsys, full_disk):
    old = tmp_path / "run.csv"
    old.write_text("previous run\n")
    _run(capsys, RUN + ["--out", str(old), "--force"], 1)
    assert old.read_text() == "previous run\n" and _leftovers(tmp_path) == []


# ------------------------------------------------------------------ the helper
def test_outputs_get_the_permissions_a_plain_write_gives(tmp_path, capsys):
    """A new output is 0o666 less the umask, as open() makes it (not mkstemp's 0o600); a replaced one keeps its mode."""
    old = os.umask(0o022)
    try:
        _run(capsys, RUN + ["--out", str(tmp_path / "x.csv"), "--plot", str(tmp_path / "x.png")], 0)
        assert oct((tmp_path / "x.csv").stat().st_mode & 0o777) == oct(0o644)
        assert oct((tmp_path / "x.png").stat().st_mode & 0o777) == oct(0o644)
        os.chmod(tmp_path / "x.csv", 0o640)
        _run(capsys, RUN + ["--out", str(tmp_path / "x.csv"), "--force"], 0)
        assert oct((tmp_path / "x.csv").stat().st_mode & 0o777) == oct(0o640)
    finally:
        os.umask(old)


def test_atomic_output_renames_only_on_success(tmp_path):
    path = tmp_path / "a.bin"
    with pytest.raises(RuntimeError):
        with atomic_output(path) as f:
            f.write(b"half")
            raise RuntimeError("interrupted")
    assert list(tmp_path.iterdir()) == []
    with atomic_output(path) as f:
        f.write(b"whole")
        assert not path.exists()  # invisible until complete
    assert path.read_bytes() == b"whole" and _leftovers(tmp_path) == []
    with pytest.raises(OutputRefused, match="exists"):
        with atomic_output(path) as f:
            pass
    with atomic_output(path, force=True, mode="w") as f:
        f.write("text\n")
    assert path.read_text() == "text\n"


def test_output_error_is_a_failed_run_not_bad_input():
    assert issubclass(OutputError, OSError)


@pytest.mark.parametrize("sig, name", [(signal.SIGTERM, "run.csv"), (signal.SIGTERM, "run.mcap"), (signal.SIGINT, "run.csv"),
                                       (signal.SIGTERM, "bag")])
def test_a_run_killed_while_writing_leaves_no_partial_file_and_keeps_the_old_one(tmp_path, sig, name):
    """A real ``belt-drive sim`` child streaming --out is signalled once its temporary file holds data:
    it exits 128 + the signal number with one line, the temporary file is gone and the old output
    (replaced only on success, --force) is untouched. A bag folder (--bag-folder, written in place)
    is removed, files of others in it kept."""
    out = tmp_path / name
    if name == "bag":
        out.mkdir()
        (out / "notes.txt").write_text("mine")
        growing = lambda: list(out.glob("bag_*.mcap"))  # noqa: E731
    else:
        out.write_bytes(b"old")
        growing = lambda: list(tmp_path.glob(f".{name}.*.part"))  # noqa: E731
    # long enough that the signal lands mid-run: the first windows are written after the guards (which
    # scale with the duration: ~50 s under load at 100,000 s), the rest takes seconds more to write (~18 s
    # at load 12). A child that ended before the signal could be sent (this process starved that long)
    # proves nothing either way: the run is repeated ten times longer, once.
    for duration in ("10000", "100000"):
        cmd = [sys.executable, "-m", "belt_drive_ros.cli", "sim", "paper", "--duration", duration, "--quiet",
               "--force", "--out", str(out)] + (["--bag-folder"] if name == "bag" else [])
        # (PYTHONFAULTHANDLER: a child still running long after the signal is sent SIGABRT, on which it prints
        # every thread's stack from C, even with the interpreter's lock held or the signal never handled)
        child = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, cwd=tmp_path.parent,
                                 env={**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1]),
                                      "PYTHONFAULTHANDLER": "1"},
                                 preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
        try:
            deadline = time.monotonic() + 300.0
            while not any(p.stat().st_size > 0 for p in growing()):
                assert child.poll() is None, child.stderr.read()
                assert time.monotonic() < deadline, "no output appeared"
                time.sleep(0.05)
            ended_first = child.poll() is not None  # then send_signal sends nothing
            child.send_signal(sig)
            try:
                err = child.communicate(timeout=120)[1]
            except subprocess.TimeoutExpired:
                child.send_signal(signal.SIGABRT)
                try:
                    err = child.communicate(timeout=30)[1]
                except subprocess.TimeoutExpired:
                    child.kill()
                    err = child.communicate()[1]
                pytest.fail(f"still running 120 s after {sig!r}; its stderr (stacks at SIGABRT): {err}")
        finally:
            if child.poll() is None:
                child.kill()
                child.wait()
        if not ended_first:
            break
        assert duration == "10000", "the run ended before it could be signalled, twice"
        if name == "bag":
            for f in out.iterdir():
                if f.name != "notes.txt":
                    f.unlink()
        else:
            out.write_bytes(b"old")
    assert child.returncode == 128 + sig, err
    lines = err.strip().splitlines()
    assert lines == [f"belt-drive: interrupted by {signal.Signals(sig).name}; unfinished outputs removed"], err
    assert _leftovers(tmp_path) == [] and sorted(p.name for p in tmp_path.iterdir()) == [name]
    if name == "bag":
        assert sorted(p.name for p in out.iterdir()) == ["notes.txt"]
    else:
        assert out.read_bytes() == b"old"


STUCK_CLEANUP = """
import sys, threading
from belt_drive_ros.io import atomic, run_writers
atomic.CLEANUP_LIMIT = 3.0
def stuck_abort(self):
    threading.Event().wait()  # a cleanup that never ends (a lock no one releases)
run_writers.McapWindows.abort = stuck_abort
sys.argv = ["belt-drive"] + sys.argv[1:]
from belt_drive_ros.cli import main
sys.exit(main())
"""


def test_an_interrupted_program_whose_cleanup_sticks_ends_with_its_threads_stacks(tmp_path):
    """The bound on an interrupted program's cleanup (io.atomic.CLEANUP_LIMIT, 3 s here): a real ``belt-drive
    sim --out x.mcap`` child whose window writer's abort never returns is SIGTERMed once its output holds
    data; the watchdog armed by the signal ends it with exit 1, every thread's stack (the stuck abort's frame
    among them) on stderr, instead of a process that hangs until killed."""
    out = tmp_path / "run.mcap"
    child = subprocess.Popen([sys.executable, "-c", STUCK_CLEANUP, "sim", "paper", "--duration", "100000", "--quiet",
                              "--out", str(out)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                             cwd=tmp_path, env={**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])})
    try:
        deadline = time.monotonic() + 300.0
        while not any(p.stat().st_size > 0 for p in tmp_path.glob(".run.mcap.*.part")):
            assert child.poll() is None, child.stderr.read()
            assert time.monotonic() < deadline, "no output appeared"
            time.sleep(0.05)
        child.send_signal(signal.SIGTERM)
        signalled = time.monotonic()
        try:
            err = child.communicate(timeout=120)[1]
        except subprocess.TimeoutExpired:
            child.kill()
            pytest.fail(f"the watchdog did not end the stuck program; its stderr: {child.communicate()[1]}")
        waited = time.monotonic() - signalled
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()
    assert child.returncode == 1, err
    assert waited >= 3.0, waited
    assert "Timeout (0:00:03)!" in err and "in stuck_abort" in err and 'File "<string>"' in err, err
    assert "Thread 0x" in err and "most recent call first" in err, err


def test_a_failed_bag_folder_write_removes_the_bag_and_an_existing_one_is_refused_untouched(tmp_path, capsys, monkeypatch):
    from belt_drive_ros.io import recording

    bag = tmp_path / "bag"
    _run(capsys, RUN + ["--out", str(bag), "--bag-folder"], 0)
    before = sorted(p.name for p in bag.iterdir())
    assert "metadata.yaml" in before
    line = _run(capsys, RUN + ["--out", str(bag), "--bag-folder"], 2)  # exists, no --force: untouched
    assert "exist" in line and sorted(p.name for p in bag.iterdir()) == before

    def full(self, *args, **kwargs):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(recording.ResultMcapWriter, "write", full)
    fresh = tmp_path / "fresh"
    _run(capsys, RUN + ["--out", str(fresh), "--bag-folder"], 1)
    assert not fresh.exists()


def test_benchmark_tables_and_charts_appear_whole_or_not_at_all(tmp_path, monkeypatch):
    """A study interrupted while writing its CSV or PNG keeps the previous file and leaves no temporary one."""
    from belt_drive_ros.benchmarks.common import pyplot, save_figure, write_csv

    table, chart = tmp_path / "study.csv", tmp_path / "study.png"
    table.write_text("old\n"), chart.write_bytes(b"old")

    def rows():
        yield {"a": 1.0}
        raise KeyboardInterrupt  # the study stopped while the table was being written

    with pytest.raises(KeyboardInterrupt):
        write_csv(table, rows(), ["a"])
    assert table.read_text() == "old\n" and _leftovers(tmp_path) == []
    write_csv(table, [{"a": 0.5}, {"a": 2.0}], ["a"])
    assert table.read_text().splitlines() == ["a", "0.5", "2"]

    from PIL import Image

    def half_written(image, fp, *args, **kwargs):  # PIL stopped after the first bytes of the PNG
        with contextlib.ExitStack() as stack:
            f = stack.enter_context(open(fp, "wb")) if isinstance(fp, (str, os.PathLike)) else fp
            f.write(b"\x89PNG")
            raise KeyboardInterrupt

    plt = pyplot()
    with monkeypatch.context() as m:
        m.setattr(Image.Image, "save", half_written)
        with pytest.raises(KeyboardInterrupt):
            save_figure(plt.figure(), chart)
    assert chart.read_bytes() == b"old" and _leftovers(tmp_path) == []
    fig = plt.figure()
    save_figure(fig, chart)
    plt.close("all")
    assert chart.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and _leftovers(tmp_path) == []


def test_a_bag_folder_interrupted_while_its_first_file_is_begun_is_removed_and_someone_elses_is_kept(tmp_path, monkeypatch):
    """SIGTERM (Terminated) inside the writer's constructor, after it created NAME_0.mcap: the stream's abort()
    never saw a writer, so the begun file stayed behind (seen once in a loaded parallel run of the test above).
    A bag already in the folder that the writer would refuse (no --force) is never removed."""
    from belt_drive_ros.io import recording
    from belt_drive_ros.io.atomic import Terminated
    from belt_drive_ros.io.run_writers import McapWindows

    def begun_then_terminated(path, window, **options):
        first = Path(path) / (Path(path).name + "_0.mcap")
        if not first.exists():  # (the real writer checks before it writes)
            first.write_bytes(b"\x89MCAP0\r\n")
        raise Terminated(signal.SIGTERM)

    monkeypatch.setattr(recording, "ResultMcapWriter", begun_then_terminated)
    ours = tmp_path / "ours"
    ours.mkdir()
    (ours / "notes.txt").write_text("mine")
    with pytest.raises(Terminated):
        McapWindows(ours, bag_folder=True).add(None)
    assert sorted(p.name for p in ours.iterdir()) == ["notes.txt"]

    theirs = tmp_path / "theirs"
    theirs.mkdir()
    (theirs / "theirs_0.mcap").write_bytes(b"recorded")
    with pytest.raises(Terminated):
        McapWindows(theirs, bag_folder=True).add(None)  # (the real writer refuses it; an interrupt must not remove it)
    assert (theirs / "theirs_0.mcap").read_bytes() == b"recorded"
