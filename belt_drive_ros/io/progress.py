"""Progress of runs that take longer than a moment, and an estimate of a long run before it starts.

On a terminal, :class:`ProgressBar` redraws one bar line on stderr; when
stderr is a file or a pipe (a CI log, ``nohup``, ``2> log``) it prints a
plain line every 10 % of the run or every 30 s, whichever comes first, so
a log shows how far a run got and how long it still needs.
:func:`estimate_run` times two short trial runs of the same scene and
output format and extrapolates the size of the output and the run's
wall time to the full duration.
"""

from __future__ import annotations

import io
import sys
import time
from dataclasses import dataclass


def _duration(seconds: float) -> str:
    """``42 s``, ``12 min``, ``3.4 h`` (rounded for people)."""
    if seconds < 120:
        return f"{seconds:.0f} s"
    if seconds < 5400:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"


def _size(nbytes: float) -> str:
    for unit, scale in (("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if nbytes >= scale:
            return f"{nbytes / scale:.3g} {unit}"
    return f"{nbytes:.0f} B"


class ProgressBar:
    """Callable ``bar(fraction)`` of a run's progress, on stderr (or ``stream``).

    Nothing before ``delay`` s. On a terminal (or ``force``) a bar redrawn in
    place; otherwise, unless ``lines=False``, a line each ``line_step`` of
    the run (10 %) or each ``line_interval`` s (30 s), whichever is first,
    with the time elapsed and left, from ``line_delay`` s on (5 s: a run that
    ends sooner fills no log with lines). ``clock`` [s] is replaceable for tests.
    """

    def __init__(self, label: str, delay: float = 0.5, stream=None, force: bool = False, width: int = 30,
                 lines: bool = True, line_step: float = 0.1, line_interval: float = 30.0, clock=time.perf_counter,
                 line_delay: float = 5.0):
        self.label, self.delay, self.width = label, delay, width
        self.stream = stream or sys.stderr
        self.bar = force or getattr(self.stream, "isatty", lambda: False)()
        self.lines = lines and not self.bar
        if self.lines:
            self.delay = max(delay, line_delay)
        self.enabled = self.bar or self.lines
        self.line_step, self.line_interval, self.clock = line_step, line_interval, clock
        self.start = clock()
        self.drawn = False
        self.last_line_fraction, self.last_line_time = 0.0, self.start

    def __call__(self, fraction: float) -> None:
        if not self.enabled:
            return
        now = self.clock()
        elapsed = now - self.start
        if elapsed < self.delay and fraction < 1.0:
            return
        if fraction >= 1.0 and not self.drawn:
            return
        fraction = min(max(fraction, 0.0), 1.0)
        eta = elapsed / fraction - elapsed if fraction > 0 else float("nan")
        if self.lines:
            self._line(fraction, now, elapsed, eta)
            return
        filled = int(self.width * fraction)
        self.stream.write(
            f"\r{self.label} [{'#' * filled}{'.' * (self.width - filled)}] {100 * fraction:5.1f}% "
            f"{elapsed:5.1f}s eta {eta:4.1f}s"
        )
        if fraction >= 1.0:
            self.stream.write("\n")
        self.stream.flush()
        self.drawn = True

    def _line(self, fraction: float, now: float, elapsed: float, eta: float) -> None:
        """One plain line at each ``line_step`` of the run, each ``line_interval`` s, and at the end."""
        if fraction >= 1.0 and self.last_line_fraction >= 1.0:
            return  # the end is said once
        step_due = int(fraction / self.line_step + 1e-9) > int(self.last_line_fraction / self.line_step + 1e-9)
        if not (fraction >= 1.0 or step_due or now - self.last_line_time >= self.line_interval):
            return
        left = "" if fraction >= 1.0 or eta != eta else f", ~{_duration(eta)} left"
        self.stream.write(f"{self.label}: {100 * fraction:.0f}% after {_duration(elapsed)}{left}\n")
        self.stream.flush()
        self.drawn = True
        self.last_line_fraction, self.last_line_time = fraction, now


@dataclass(frozen=True)
class RunEstimate:
    """A long run's output size [bytes] (None without an output) and wall time [s], extrapolated from two trials."""

    nbytes: float | None
    seconds: float
    trial: tuple[float, float]

    def describe(self, label: str, out=None) -> str:
        size = f"--out {out} ~{_size(self.nbytes)}, " if self.nbytes is not None and out is not None else ""
        return (f"{label}: estimate: {size}~{_duration(self.seconds)} on this machine now "
                f"(from trial runs of {self.trial[0]:g} s and {self.trial[1]:g} s of it; Ctrl-C stops the run "
                f"and removes the unfinished output)")


#: the longer trial spans this many steps (of the integrator or the output, the finer) or this share of
#: the run, whichever is more, at most TRIAL_MAX steps; the shorter one a third of it. A warm-up run of
#: TRIAL_WARMUP steps goes first (imports, caches), uncounted.
TRIAL_STEPS, TRIAL_SHARE, TRIAL_MAX, TRIAL_WARMUP = 6000, 0.01, 100000, 200


def estimate_run(scene, out_format: str | None, clock=time.perf_counter) -> RunEstimate:
    """Time two short runs of ``scene`` (and their output in ``out_format``: csv, mcap or None, in memory).

    The size and time of a run are an overhead plus a part that grows with
    the simulated duration; the two trials (:data:`TRIAL_STEPS` ... of the
    finer of the integrator step and the output interval) give the slope,
    and the estimate is the longer trial's figure extrapolated along it to
    the scene's duration (a longer trial timed no slower than the shorter
    one, noise on a cheap scene, extrapolates its whole time in proportion:
    an upper bound, never ~0 s). Stream windows, auto's model choice and the
    writers are those of the real run; only the disk is not. A run whose
    signals settle compresses better later on than in the trials (MCAP's
    zstd chunks): its file comes out smaller than estimated (``paper``,
    3000 s: 111 MB estimated from 10 s and 30 s trials, 91 MB written;
    74 s estimated, 55-58 s taken, on a machine with a load average of 8).
    """
    from ..core.stream import Restart, stream
    from .run_writers import CsvWindows, McapWindows

    h = min(scene.dt, 1.0 / scene.output_rate) if scene.output_rate else scene.dt
    longer = min(max(TRIAL_STEPS * h, TRIAL_SHARE * scene.duration), TRIAL_MAX * h, scene.duration)
    spans = (longer / 3.0, longer)
    for _ in stream(scene.with_overrides(duration=min(TRIAL_WARMUP * h, scene.duration))):
        pass
    measured = []
    for span in spans:
        buffer = io.StringIO() if out_format == "csv" else io.BytesIO()
        sink = None if out_format is None else (CsvWindows(buffer) if out_format == "csv" else McapWindows(buffer, start_time_ns=0))
        t0 = clock()
        for window in stream(scene.with_overrides(duration=span)):
            if sink is not None:
                sink.restart() if isinstance(window, Restart) else sink.add(window)
        if sink is not None:
            sink.close()
        measured.append((clock() - t0, len(buffer.getvalue())))
    (w1, b1), (w2, b2) = measured
    grow = (scene.duration - spans[1]) / (spans[1] - spans[0]) if spans[1] > spans[0] else 0.0
    # the longer trial timed no slower than the shorter (the machine's noise hid the slope): all of it grows
    seconds = w2 + ((w2 - w1) if w2 > w1 else w2 * (spans[1] - spans[0]) / spans[1]) * grow
    nbytes = b2 + max(b2 - b1, 0) * grow if out_format is not None else None
    return RunEstimate(nbytes, seconds, spans)
