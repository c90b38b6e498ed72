"""Gaps in the node's ticks: stretches of its tick grid never published (no rclpy).

On the system clock the node publishes every tick of its grid
``origin + k / step_rate_hz``; a tick thread that wakes late catches up
tick by tick up to :data:`~belt_drive_ros.ros.timing.MAX_THREAD_CATCH_UP_NS`
behind. Beyond that (the process was stopped by SIGSTOP or a suspend,
starved of CPU, or the system clock stepped forward) it integrates to the
latest grid point in one go, and the executor timer (``tick_thread:=false``)
does so whenever it runs more than a period late: the ticks in between are
never published. A clock switch (``use_sim_time`` toggled, ``publish_clock``
turned off) restarts the run on the new time base, with no ticks in between
either. Each such stretch is a :class:`TickGap`:

* ``start_ns``: the last tick made before it, ``end_ns``: the first after it
  [ns, the node's time base; across a clock switch the two are on different
  bases];
* ``missed``: the ticks of the grid never published in between,
  ``(end - start) / tick - 1`` on one grid; across a clock switch none (the
  time between is no tick the node owed: ``/clock`` waits are the time
  master's, and the run restarts on the new base; the cause says how much
  wall time passed);
* ``cause``: what is known: a clock switch (which), the system clock stepped
  forward (its step exceeds the monotonic time that passed), or the process
  not running (monotonic time passed as well: SIGSTOP, suspend, starvation).

On ``/clock`` the ticks follow the time master: a ``/clock`` jump is its
decision, the node integrates exactly to the new time and reports no gap;
with ``publish_clock`` the node's simulated time never skips a tick.

:class:`TickGaps` finds them (:meth:`TickGaps.tick` before every tick,
:meth:`TickGaps.switched` at a clock switch), counts them (``tick_gaps``,
``ticks_missed``), keeps the last one for ``/diagnostics``, logs them (at
most one line a second; the rest are counted in the next line) and hands
each to ``on_gap`` (the node records it as an MCAP metadata record named
:data:`TICK_GAP_METADATA`, which ``msg-tools info`` lists). Short gaps (under
:data:`SHORT_GAP_NS`: an executor timer a few periods late, as
``tick_thread:=false`` has on a loaded machine) are each counted, but handed
on together, one aggregate gap per second at most (:meth:`TickGaps.flush`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable

from msg_tools.results import TICK_GAP_METADATA

__all__ = ["TICK_GAP_METADATA", "TickGap", "TickGaps", "next_tick_ns"]

#: at most one log line per this many ns of monotonic time (the gaps in between are counted in it)
LOG_EVERY_NS = 1_000_000_000
#: a gap shorter than this [ns of node time] is *short* (an executor timer a few periods late, ~100 a
#: second on a loaded machine with ``tick_thread:=false``): the short ones of up to SHORT_WINDOW_NS of
#: monotonic time are handed on as one aggregate gap, so that a recording gets at most a record a second
SHORT_GAP_NS = 50_000_000
SHORT_WINDOW_NS = 1_000_000_000


def next_tick_ns(t_ns: int, origin_ns: int, tick_ns: int) -> int:
    """The first point of the tick grid ``origin_ns + k tick_ns`` after time ``t_ns`` [ns] (the node's ticks; the
    torque source's on ``/clock``)."""
    return t_ns + tick_ns - (t_ns - origin_ns) % tick_ns


@dataclass(frozen=True)
class TickGap:
    """One stretch of the tick grid never published (module docstring)."""

    start_ns: int
    end_ns: int
    missed: int
    cause: str
    time_base: str

    @property
    def duration_s(self) -> float:
        """``end - start`` [s] (across a clock switch: of the two time bases, as stamped)."""
        return (self.end_ns - self.start_ns) / 1e9

    def describe(self) -> str:
        return (f"{self.missed} tick(s) missed between {self.start_ns / 1e9:.6f} s and {self.end_ns / 1e9:.6f} s "
                f"({self.time_base}): {self.cause}")

    def metadata(self) -> dict[str, str]:
        """The MCAP metadata record's values (strings; times in integer ns)."""
        return {"start_ns": str(self.start_ns), "end_ns": str(self.end_ns), "ticks_missed": str(self.missed),
                "cause": self.cause, "time_base": self.time_base}


class TickGaps:
    """Finds, counts and reports the gaps in a node's ticks (module docstring).

    Parameters
    ----------
    counters : dict
        The node's counters; ``tick_gaps`` and ``ticks_missed`` are added.
    warn : callable
        Takes one log line.
    """

    def __init__(self, counters: dict, warn: Callable[[str], None]):
        self.counters = counters
        counters.setdefault("tick_gaps", 0)
        counters.setdefault("ticks_missed", 0)
        self.warn = warn
        #: called with each gap found (the node records it)
        self.on_gap: Callable[[TickGap], None] | None = None
        self.last: TickGap | None = None
        #: monotonic time of the last tick made [ns] (a tick source that knows :meth:`tick` finds no gap
        #: sets it instead of calling it: the tick thread's usual tick)
        self.mono: int | None = None
        #: the node's time (the system clock) [ns] when that tick was made: a late tick's is later than its own time
        #: (with :attr:`mono` it tells a clock that stepped from a tick source that fell behind its ticks)
        self.real: int | None = None
        self._switch: tuple | None = None  # (last tick [ns], its monotonic time [ns], bases so far)
        self._logged_at: int | None = None
        self._unlogged = 0
        #: short gaps not handed on yet: [first gap, its monotonic time, count, ticks missed, last end, longest], or None
        self.short: list | None = None

    def tick(self, t_ns: int | None, now_ns: int, tick_ns: int, time_base: str, source: str) -> None:
        """Before a tick integrates from ``t_ns`` (None: the run starts) to ``now_ns`` on ``time_base``.

        A gap is the first tick after a clock switch, or, on the system clock,
        a tick more than one period after the last one (``source`` names the
        tick source: "tick thread", "executor timer").
        """
        mono = time.monotonic_ns()
        if self.short is not None and mono - self.short[1] > SHORT_WINDOW_NS:
            self.flush()
        if t_ns is None:
            if self._switch is not None:
                last, last_mono, bases = self._switch
                self._switch = None
                wall = mono - last_mono
                chain = bases if bases[-1] == time_base else bases + [time_base]
                self._add(TickGap(last, now_ns, 0,
                                  f"clock switched ({' -> '.join(chain)}); the run restarted after "
                                  f"{wall / 1e9:.3f} s of wall time without ticks", f"{bases[0]} -> {time_base}"))
        elif time_base == "system" and now_ns - t_ns > tick_ns:
            step = now_ns - t_ns
            wall = None if self.mono is None else mono - self.mono
            # the system clock moved by more than monotonic time did since the last tick: it stepped (a tick source
            # behind its ticks made the last one late, its node time far behind the clock: no step)
            moved = None if self.real is None else now_ns - self.real
            if step < SHORT_GAP_NS:
                cause = f"the {source} ran {step / 1e6:.3g} ms after the last tick and integrated to the latest tick"
            elif wall is not None and moved is not None and moved - wall > max(tick_ns, step // 2):
                cause = (f"the system clock stepped forward ({step / 1e9:.3f} s of node time in "
                         f"{wall / 1e9:.3f} s of monotonic time); the {source} integrated to the latest tick")
            else:
                cause = (f"no tick for {step / 1e9:.3f} s: the process was stopped (SIGSTOP, suspend) or starved "
                         f"of CPU; the {source} integrated to the latest tick")
            self._add(TickGap(t_ns, now_ns, step // tick_ns - 1, cause, time_base), short=step < SHORT_GAP_NS)
        self.mono, self.real = mono, now_ns

    def switched(self, t_ns: int | None, old_base: str, new_base: str) -> None:
        """The node's clock switched from ``old_base`` to ``new_base``; the last tick was at ``t_ns``
        (None: no tick since the previous switch, which stays the start of the gap)."""
        if self._switch is not None:
            last, last_mono, bases = self._switch
            self._switch = (last, last_mono, bases + [new_base])
        elif t_ns is not None:
            self._switch = (t_ns, self.mono if self.mono is not None else time.monotonic_ns(), [old_base, new_base])

    def flush(self) -> None:
        """Hand on the short gaps collected so far as one aggregate gap (also when the node ends)."""
        short, self.short = self.short, None
        if short is None or self.on_gap is None:
            return
        first, _, count, missed, end, longest = short
        if count == 1:
            self.on_gap(first)
            return
        self.on_gap(TickGap(first.start_ns, end, missed, f"{count} short gaps (each under "
                            f"{SHORT_GAP_NS / 1e6:g} ms, the longest {longest / 1e6:.3g} ms; first: {first.cause})",
                            first.time_base))

    def _add(self, gap: TickGap, short: bool = False) -> None:
        self.counters["tick_gaps"] += 1
        self.counters["ticks_missed"] += gap.missed
        self.last = gap
        mono = time.monotonic_ns()
        if short:
            if self.short is None:
                self.short = [gap, mono, 0, 0, 0, 0]
            agg = self.short
            agg[2] += 1
            agg[3] += gap.missed
            agg[4] = gap.end_ns
            agg[5] = max(agg[5], gap.end_ns - gap.start_ns)
        else:
            self.flush()
            if self.on_gap is not None:
                self.on_gap(gap)
        if self._logged_at is not None and mono - self._logged_at < LOG_EVERY_NS:
            self._unlogged += 1
            return
        more = f" (and {self._unlogged} more gap(s) since the last line)" if self._unlogged else ""
        self._logged_at, self._unlogged = mono, 0
        self.warn(f"gap in the ticks: {gap.describe()}{more}")
