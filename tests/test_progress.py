"""Progress of long runs when stderr is not a terminal, and the estimate printed before a long run."""

from __future__ import annotations

import functools
import io

import pytest

from belt_drive_ros.cli import main
from belt_drive_ros.commands import sim as sim_command
from belt_drive_ros.core import stream as stream_module
from belt_drive_ros.io.scenes import load_scene
from belt_drive_ros.io.progress import ProgressBar, estimate_run


class FakeClock:
    def __init__(self):
        self.now = 100.0

    def __call__(self):
        return self.now


class Tty(io.StringIO):
    def isatty(self):
        return True


def test_lines_every_tenth_and_every_30_s_when_not_a_terminal():
    clock, out = FakeClock(), io.StringIO()
    bar = ProgressBar("sim paper", stream=out, clock=clock)
    for k in range(1, 1001):  # 1000 calls over 80 s: a line per 10 % (8 s), none in between
        clock.now += 0.08
        bar(k / 1000)
    lines = out.getvalue().splitlines()
    assert [line.split(":")[1].split("%")[0].strip() for line in lines] == [str(p) for p in range(10, 101, 10)]
    assert lines[0] == "sim paper: 10% after 8 s, ~72 s left" and lines[-1] == "sim paper: 100% after 80 s"

    clock, out = FakeClock(), io.StringIO()
    bar = ProgressBar("sim slow", stream=out, clock=clock)
    for k in range(1, 11):  # 0.1 % per 10 s: a line each 30 s, no tenth reached
        clock.now += 10.0
        bar(k / 1000)
    assert out.getvalue().splitlines() == [
        "sim slow: 0% after 30 s, ~2.8 h left", "sim slow: 1% after 60 s, ~2.8 h left", "sim slow: 1% after 90 s, ~2.8 h left",
    ]


def test_terminal_keeps_its_bar_and_nothing_before_the_delay():
    clock, out = FakeClock(), Tty()
    bar = ProgressBar("sim paper", stream=out, clock=clock)
    bar(0.5)  # before the delay: nothing
    assert out.getvalue() == ""
    clock.now += 2.0
    bar(0.5)
    bar(1.0)
    assert out.getvalue().startswith("\rsim paper [###############...............]  50.0%")
    assert out.getvalue().endswith("\n") and out.getvalue().count("\n") == 1
    quiet = io.StringIO()
    ProgressBar("x", stream=quiet, lines=False, clock=clock)(0.5)
    assert quiet.getvalue() == ""


@pytest.mark.parametrize("fmt", ["mcap", "csv"])
def test_estimate_is_near_the_size_written(tmp_path, fmt):
    scene = load_scene("paper").with_overrides(duration=120.0)
    estimate = estimate_run(scene, fmt)
    out = tmp_path / f"run.{fmt}"
    assert main(["sim", "paper", "--duration", "120", "--out", str(out), "--quiet"]) == 0
    written = out.stat().st_size
    assert 0.7 * written < estimate.nbytes < 1.5 * written, (estimate.nbytes, written)
    assert estimate.seconds > 0 and estimate.trial[1] == pytest.approx(6.0)
    assert estimate_run(scene, None).nbytes is None


def test_an_estimate_whose_trials_timed_backwards_grows_in_proportion_not_to_zero():
    """Noise can time the longer trial no slower than the shorter (a cheap scene on a busy machine): the
    estimate then scales the longer trial's whole time to the duration, as if it had no overhead."""
    ticks = iter([0.0, 0.5, 10.0, 10.4])  # the short trial 0.5 s, the long one 0.4 s
    scene = load_scene("paper").with_overrides(duration=600.0)
    estimate = estimate_run(scene, None, clock=lambda: next(ticks))
    assert estimate.seconds == pytest.approx(0.4 * 600.0 / estimate.trial[1])


def test_a_streamed_sim_says_its_estimate_then_progress_lines(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(sim_command, "STREAM_ABOVE", 1000)  # stream a short run, as a long one is,
    monkeypatch.setattr(stream_module, "WINDOW_STEPS", 500)  # in windows of 2.5 s (progress after each)
    monkeypatch.setattr(ProgressBar, "__init__", functools.partialmethod(ProgressBar.__init__, delay=0.0, line_delay=0.0))
    out = tmp_path / "run.mcap"
    assert main(["sim", "paper", "--duration", "30", "--out", str(out)]) == 0
    err = capsys.readouterr().err.splitlines()
    assert err[0].startswith(f"sim paper: estimate: --out {out} ~") and " MB, ~" in err[0]
    assert err[-1].startswith("sim paper: 100% after ")
    assert len([line for line in err if "% after" in line]) >= 2
    assert main(["sim", "paper", "--duration", "30", "--out", str(out), "--force", "--quiet"]) == 0
    assert capsys.readouterr().err == ""


def test_a_run_that_ends_within_the_line_delay_prints_no_progress_lines():
    """Not a terminal: a 1 s run printed ten progress lines (review); lines start after line_delay (5 s)."""
    clock, out = FakeClock(), io.StringIO()
    bar = ProgressBar("sim short", stream=out, clock=clock)
    for k in range(1, 11):
        clock.now += 0.1
        bar(k / 10)
    assert out.getvalue() == ""
    slow = ProgressBar("sim long", stream=out, clock=clock)
    for k in range(1, 11):
        clock.now += 1.0
        slow(k / 10)
    lines = out.getvalue().splitlines()
    assert lines and lines[0].startswith("sim long: 50% after") and lines[-1].startswith("sim long: 100% after"), lines
