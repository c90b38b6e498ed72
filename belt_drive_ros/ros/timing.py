"""The node's three tick sources and its tick statistics.

:class:`TickSource` owns the timers of a node and calls ``tick(now_ns)``
once per tick with the node time to integrate to:

* **system clock** (default): ticks at ``step_rate_hz`` on the run's tick
  grid (origin + k / step_rate_hz); the stamps stay on the grid (wake-up
  jitter shows as latency, never as uneven simulated time), and a
  recording of the run re-simulates exactly. With ``tick_thread:=true``
  (default) a thread of the node's own (:class:`TickThread`) sleeps to each
  tick's deadline and ticks; a late wake publishes every missed tick in turn
  (up to :data:`MAX_THREAD_CATCH_UP_NS` behind). The executor is not woken
  per tick: it serves inputs, parameters and services only. With
  ``tick_thread:=false`` an executor timer ticks instead; a call more than a
  period late integrates every missed tick in one go and publishes the
  latest only. Either way the run starts at the first tick after the
  executor first serves the node (scene time 0 = that tick's due time,
  truncated to whole microseconds).
* ``use_sim_time:=true``: the node follows ``/clock``, ticked by the
  ``/clock`` messages themselves (a subscription of its own, best effort and
  depth 1 as rclpy's time source reads ``/clock``, so any publisher matches).
  The run starts at the first ``/clock`` the node sees (also ``/clock`` = 0)
  and publishes the initial state stamped with it; after that a ``/clock``
  that reaches the next point of the tick grid (the run's start + k ticks)
  ticks once, however far it jumps, and the tick integrates exactly to that
  message's time; one back in time restarts the run there. The outputs are
  a deterministic function of the ``/clock`` and torque sequences
  (bit-identical reruns), and a driver stepping ``/clock`` by one tick gets
  exactly one tick per step. (An rclpy timer on simulated time, the earlier
  tick source, did not guarantee that under the events executor: on a
  loaded machine it fired twice at one ``/clock`` time and then not at the
  next, and the node stopped ticking.)
* ``publish_clock:=true``: the node is the time master. It advances its own
  simulated time by whole ticks, paced by a wall (steady) timer at
  ``real_time_factor`` (0: as fast as the CPU allows, in 2 ms slices of
  back-to-back ticks between which inputs are served), and after each tick
  publishes the outputs and then ``/clock`` with the *same* time. A late
  wall timer catches up tick by tick, each published with its ``/clock``
  (at most 1 s of simulated time; beyond that the pacing re-anchors with one
  tick instead of bursting: the time master slows, it never skips a tick). The run starts at simulated
  time 0 (its first tick, whenever the first timer call comes).

:class:`TickStats` keeps the wall-clock tick periods (a ring of 4096), late
ticks and overruns for ``/diagnostics``.
"""

from __future__ import annotations

import threading
import time
from typing import Callable

import numpy as np
from rclpy.clock import Clock, ClockType, JumpThreshold
from rosgraph_msgs.msg import Clock as ClockMsg

from . import environment as ros_env
from .gaps import TickGaps, next_tick_ns
from .qos import CLOCK_QOS, CLOCK_TICK_QOS

__all__ = ["TickSource", "TickStats", "TickThread", "stamp"]

#: on the system clock the run's origin is truncated to whole microseconds
SYSTEM_TIME_QUANTUM_NS = 1000
#: publish_clock as fast as possible: ticks run back to back for this much wall
#: time per callback of a wall timer of this period, then the executor serves inputs
FREE_RUN_SLICE_S = 0.002
FREE_RUN_PERIOD_S = 0.0005
#: a publish_clock timer call catches up at most this much simulated time [ns], tick by tick, after the wall timer
#: was late; beyond it the pacing re-anchors with one tick (the time master slows; no tick is skipped).
MAX_CATCH_UP_NS = 1_000_000_000
#: the tick thread publishes each missed tick when it wakes up to this late [ns];
#: later (the process was stopped, the clock stepped) it integrates to the latest tick in one go
MAX_THREAD_CATCH_UP_NS = 50_000_000
#: the tick thread sleeps at most this long at once [s] (a stop or a clock step is seen within it)
MAX_SLEEP_S = 0.05
#: the tick thread's lead covers the LEAD_PERCENTILE-th percentile of its last LEAD_WINDOW ticks' computation
#: plus LEAD_MARGIN_NS (re-estimated every LEAD_UPDATE ticks; at most 3/4 of a period)
LEAD_WINDOW = 1024
#: late ticks stay well below 1 % (a p99 lead left ~1 % late: the one-way latency's p99 itself)
LEAD_PERCENTILE = 99.9
LEAD_UPDATE = 256
LEAD_MARGIN_NS = 100_000
#: the tick thread's name, also the operating system's (``/proc/PID/task/TID/comm``): its CPU time is found by it
THREAD_NAME = ros_env.TICK_THREAD


def stamp(msg_time, ns: int) -> None:
    """Set a ``builtin_interfaces/Time`` to ``ns`` nanoseconds."""
    msg_time.sec, msg_time.nanosec = divmod(int(ns), 1_000_000_000)


class Window:
    """Counters of one diagnostics window (reset after each publish)."""

    __slots__ = ("ticks", "overruns", "late_ticks", "slack", "slip", "divergences", "wall")

    def __init__(self):
        self.ticks = self.overruns = self.late_ticks = self.slack = self.slip = self.divergences = 0
        self.wall = time.perf_counter()


class TickStats:
    """Wall-clock timing of the ticks: period ring buffer, late ticks, overruns."""

    def __init__(self, counters: dict, size: int = 4096):
        self.counters = counters
        for key in ("ticks", "overruns", "late_ticks"):
            counters.setdefault(key, 0)
        self.periods = [0.0] * size  # the last `size` tick intervals [s of wall time] (a list: a tick sets one cheaply)
        self.n_periods = 0
        self.window = Window()
        self.prev_start: float | None = None

    def new_window(self) -> Window:
        """Return the finished window and start a new one."""
        w, self.window = self.window, Window()
        return w

    def record(self, start: float, end: float, nominal: float | None) -> None:
        """One tick that ran from ``start`` to ``end`` [s, perf_counter]; ``nominal`` period [s] or None (untimed)."""
        w = self.window
        w.ticks += 1
        self.counters["ticks"] += 1
        prev = self.prev_start
        self.prev_start = start
        if prev is None:
            return
        interval = start - prev
        self.periods[self.n_periods % len(self.periods)] = interval
        self.n_periods += 1
        if nominal is not None:
            if interval > 1.5 * nominal:
                w.late_ticks += 1
                self.counters["late_ticks"] += 1
            if end - start > nominal:
                w.overruns += 1
                self.counters["overruns"] += 1

    def period_error_ms(self, nominal: float) -> tuple[float, float, float]:
        """|period - nominal| [ms]: p50, p99, max over the ring (NaN without data)."""
        n = min(self.n_periods, len(self.periods))
        if not n:
            return (float("nan"),) * 3
        err = np.abs(np.asarray(self.periods[:n]) - nominal) * 1e3
        return tuple(float(v) for v in np.percentile(err, [50, 99, 100]))


class TickThread:
    """System-clock ticks from a thread of the node's own (``tick_thread:=true``, the default).

    The thread sleeps to the deadline of the next tick of the run's grid
    (the system clock, CLOCK_REALTIME, as the node stamps), takes the
    source's lock (every callback that touches the simulation holds it too)
    and ticks. An executor timer instead wakes the executor for every tick
    (``rcl_wait``, then its Python dispatch: about 0.2 ms of CPU per tick
    measured in ``belt-drive bench node --floor``) and drops a tick it
    serves more than a period late. Here a late wake ticks every missed
    grid point in turn, each published with its own stamp, when it is at
    most :data:`MAX_THREAD_CATCH_UP_NS` behind; further behind, it
    integrates to the latest grid point in one go (counted as a late tick).
    The lock is released between ticks; the input callbacks do not take it
    (they hand over under a lock of their own, taken by a tick at its start),
    so an input received while a tick computes is served at once and applies
    from the next tick, as with a timer.

    Each tick is computed ahead of its due time and published at it. The
    lead is ``tick_lead`` or, when the thread's recent ticks took longer
    (the slipping model's ticks with stick/slip events cost several times a
    plain one), the 99.9th percentile of the last :data:`LEAD_WINDOW` ticks'
    computation plus :data:`LEAD_MARGIN_NS`; at most 3/4 of a period. ``lead_ns``
    is the lead in force (``/diagnostics`` shows it).

    A tick computed but not yet published when the thread is stopped (a
    reconfiguration, ``/clock`` taking over, the node's end) is published by
    :meth:`stop` at once, under the lock, so it goes out before any tick of
    the source that replaces the thread.

    An exception inside a tick ends the thread; it is kept in ``failure``
    (the node raises it from its executor: the process does not go on
    silently without ticks).
    """

    def __init__(self, source: "TickSource"):
        self.source = source
        self.failure: BaseException | None = None
        self.lead_ns = 0  # the lead in force [ns]
        self._busy = [0] * LEAD_WINDOW  # computation time of the latest ticks [ns] (a ring; a list: set cheaply)
        self._n_busy = 0
        self._next_update, self._settings = 0, None
        self._nominal = 0.0  # the nominal period [s] of the settings in force (see _lead)
        self._stopping = False  # set by stop() (a plain flag: the thread reads it twice per tick)
        self._pending: list | None = None  # the (publish, data) calls of the tick computed ahead
        self._thread = threading.Thread(target=self._run, name=THREAD_NAME, daemon=True)

    def start(self) -> None:
        self._thread.start()

    def alive(self) -> bool:
        return self._thread.is_alive()

    def stop(self, join: bool = True) -> bool:
        """End the thread before its next tick: publish the tick it computed ahead, if any, now.

        ``join``: wait for the thread (never while holding the lock). Returns
        False when a join timed out (the thread is still running).
        """
        with self.source.lock:
            self._stopping = True
            pending, self._pending = self._pending, None
            if pending:
                try:
                    for publish, data in pending:
                        publish(data)
                except Exception:  # noqa: BLE001 - the node or its context is going away: nothing to send to
                    pass
        if join and self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join(timeout=10.0)
            return not self._thread.is_alive()
        return True

    def _next(self, now: int) -> int | None:
        """The grid time to tick to at system time ``now`` [ns], or None when the next tick is not due yet."""
        sim = self.source.sim
        t = sim.t_ns
        if t is None or now < t:  # not started, or the system clock stepped back: the simulation (re)starts there
            return now - now % SYSTEM_TIME_QUANTUM_NS
        origin, tick = sim.origin_ns, sim.settings.tick_ns
        due = next_tick_ns(t, origin, tick)
        if now < due:
            return None
        if now - due > MAX_THREAD_CATCH_UP_NS:  # counted as a late tick by TickStats.record
            return now - (now - origin) % tick
        return due

    def compute_us(self) -> tuple[float, float]:
        """Wall time [us] the thread's latest ticks took to compute (p50, p99; of up to
        :data:`LEAD_WINDOW` ticks, NaN before the first): the tick's integration, outputs and
        encoding, under the lock, before the sleep to its due time."""
        n = min(self._n_busy, LEAD_WINDOW)
        if not n:
            return (float("nan"),) * 2
        return tuple(float(v) * 1e-3 for v in np.percentile(self._busy[:n], [50, 99]))

    def _lead(self, settings) -> int:
        """The lead [ns] for the next tick (class docstring); re-estimated every LEAD_UPDATE ticks
        and whenever the settings change."""
        n = self._n_busy
        if n >= self._next_update or settings is not self._settings:
            lead = settings.tick_lead_ns
            if n >= LEAD_UPDATE:
                lead = max(lead, int(np.percentile(self._busy[: min(n, LEAD_WINDOW)], LEAD_PERCENTILE)) + LEAD_MARGIN_NS)
            self.lead_ns = min(lead, settings.tick_ns * 3 // 4)
            self._next_update, self._settings = n + LEAD_UPDATE, settings
            self._nominal = self.source.nominal_period()
        return self.lead_ns

    def _run(self) -> None:
        ros_env.reduce_timer_slack()  # per thread: wake at the deadline, not up to 50 us after it
        ros_env.name_thread(THREAD_NAME)  # (its CPU time by name in /proc: belt-drive bench node)
        source = self.source
        sim, lock, stats, gaps, after = source.sim, source.lock, source.stats, source.gaps, source._after_tick
        now_ns, perf, mono, sleep = time.time_ns, time.perf_counter, time.monotonic_ns, time.sleep
        tick_now = source._tick
        busy_ring = self._busy
        longest, catch_up, window = MAX_SLEEP_S, MAX_THREAD_CATCH_UP_NS, LEAD_WINDOW  # (the module's, read per tick)
        try:
            while not self._stopping:
                settings = sim.settings
                if settings is self._settings and self._n_busy < self._next_update:
                    lead = self.lead_ns  # (what _lead returns between its updates)
                else:
                    lead = self._lead(settings)
                t, origin, tick = sim.t_ns, sim.origin_ns, settings.tick_ns  # without the lock: rechecked under it
                due = None if t is None else next_tick_ns(t, origin, tick)
                if due is not None:
                    wait = (due - lead - now_ns()) * 1e-9
                    if wait > 0:
                        sleep(wait if wait < longest else longest)
                with lock:
                    if self._stopping:
                        break
                    start = mono()  # (also the tick's monotonic time for the gaps)
                    now = now_ns() + lead
                    if due is not None and sim.t_ns == t and sim.origin_ns == origin and sim.settings is settings \
                            and due <= now <= due + catch_up and gaps.short is None:
                        # the usual tick: the next grid point, no gap (TickGaps.tick would find none)
                        target = due
                        gaps.mono, gaps.real = start, now - lead  # (now: the system clock plus the lead)
                    else:
                        target = self._next(now)
                        if target is None:
                            continue
                        gaps.tick(sim.t_ns, target, sim.settings.tick_ns, "system", "tick thread")
                    self._pending = tick_now(target, True)
                    busy = mono() - start
                    busy_ring[self._n_busy % window] = busy
                    self._n_busy += 1
                wait = (target - now_ns()) * 1e-9
                if wait > 0:  # computed ahead: out at the due time
                    sleep(wait)
                with lock:
                    pending, self._pending = self._pending, None
                    if pending:  # (None: stop() has published it already)
                        for publish, data in pending:
                            publish(data)
                    # the period statistics see the instants the ticks are published (their jitter is what
                    # subscribers get; read after the publish, not before it: nothing between the wake and the
                    # send); an overrun is a computation longer than the period
                    start = perf()
                    stats.record(start, start + busy * 1e-9, self._nominal)
                    if source.after_due and after is not None:  # (marked by defer_after_tick)
                        source.after_due = False
                        after()
        except BaseException as exc:  # noqa: BLE001 - kept and raised by the node's executor
            self.failure = exc
            try:
                source.node.get_logger().error(f"the tick thread stopped: {type(exc).__name__}: {exc}")
            except Exception:  # noqa: BLE001 - a dying context
                pass


class TickSource:
    """The timers that tick a node (see the module docstring).

    Parameters
    ----------
    node : rclpy.node.Node
    tick : callable
        ``tick(now_ns)``: integrate to ``now_ns`` and publish; ``tick(now_ns, True)``:
        integrate, and return the ``(publish, data)`` calls (the tick thread makes them at the due time).
    after_tick : callable, optional
        Called by the tick thread (holding the lock) after a tick's outputs are out, when
        :meth:`defer_after_tick` asked for it.
    sim : NodeSimulation
        Its time base (started, origin, grid) decides where a tick integrates to.
    stats : TickStats
    """

    def __init__(self, node, tick: Callable[..., list | None], sim, stats: TickStats,
                 after_tick: Callable[[], None] | None = None):
        self.node = node
        self._tick = tick
        self._after_tick = after_tick
        #: the tick thread calls ``after_tick`` after its next tick's outputs are out (see :meth:`defer_after_tick`)
        self.after_due = False
        self.sim = sim
        self.stats = stats
        self._timers: list = []
        self._tick_timer = None
        #: held by every tick (through its compute) and by every callback that changes the simulation (parameters,
        #: diagnostics, clock changes: the tick thread runs beside the executor); not by the input callbacks
        #: (``drive_torque``, ``~/reset``, a network's load inputs): they hand over under a lock of their own,
        #: which a tick takes at its start only, so the executor serves them while a tick computes
        self.lock = threading.RLock()
        self._thread: TickThread | None = None
        self._retired: list[TickThread] = []  # stopped without a join (from a callback holding the lock)
        self._pub_clock = None
        self._clock_msg = ClockMsg()
        self._clock_sub = None  # /clock ticks the node on simulated time (see the module docstring)
        self._clock_seen: int | None = None  # the last /clock [ns] that subscription handled
        self.sim_ns = 0  # publish_clock: the node's own simulated time
        self._anchor = (0, 0)  # publish_clock pacing: (sim ns, monotonic ns)
        self._ros_time: bool | None = None
        #: gaps in the ticks (:mod:`.gaps`): counted, the last kept, each handed to ``gaps.on_gap``
        self.gaps = TickGaps(stats.counters, lambda line: node.get_logger().warn(line))
        self._jump_handle = node.get_clock().create_jump_callback(
            JumpThreshold(min_forward=None, min_backward=None, on_clock_change=True), post_callback=self._on_clock_change
        )

    # ----------------------------------------------------------- queries
    def use_sim_time(self) -> bool:
        """True while the node's clock follows /clock (cached; updated on clock changes)."""
        if self._ros_time is None:
            self._ros_time = bool(self.node.get_clock().ros_time_is_active)
        return self._ros_time

    def now_ns(self) -> int:
        """Now on the node's time base: simulated time with publish_clock, else the node's clock."""
        if self.sim.settings.publish_clock:
            return self.sim_ns
        if self._ros_time is False:  # the node's clock is the system clock (CLOCK_REALTIME): without rclpy's Time
            return time.time_ns()
        return self.node.get_clock().now().nanoseconds

    def time_base(self) -> str:
        if self.sim.settings.publish_clock:
            return "publish_clock"
        return "sim_time" if self.use_sim_time() else "system"

    def nominal_period(self) -> float:
        """Wall-clock period [s] a tick should take on the current time base."""
        s = self.sim.settings
        nominal = s.tick_ns / 1e9
        if s.publish_clock and s.real_time_factor > 0:
            nominal /= s.real_time_factor
        return nominal

    def lead_ns(self) -> int | None:
        """The tick thread's lead in force [ns] (None without the thread)."""
        return None if self._thread is None else self._thread.lead_ns

    def compute_us(self) -> tuple[float, float] | None:
        """The tick thread's compute time per tick [us] (p50, p99; :meth:`TickThread.compute_us`), None without it."""
        return None if self._thread is None else self._thread.compute_us()

    @property
    def failure(self) -> BaseException | None:
        """The exception that ended a tick thread (None while it ticks or without one)."""
        for thread in ([self._thread] if self._thread is not None else []) + self._retired:
            if thread.failure is not None:
                return thread.failure
        return None

    def threaded(self) -> bool:
        """True while system-clock ticks come from the tick thread."""
        return self._thread is not None and self._thread.alive()

    def defer_after_tick(self) -> bool:
        """While the tick thread ticks: have it call ``after_tick`` right after its next tick is out and return
        True (the caller marks what is due first); else False (the caller does it now)."""
        if self.threaded():
            self.after_due = True
            return True
        return False

    def tick_pending(self) -> bool:
        """True while a tick is due but has not run yet (for lockstep drivers): on simulated time, while the
        node's clock is past the last ``/clock`` the tick subscription handled; else while the tick timer is due."""
        if self._clock_sub is not None and self.use_sim_time():
            seen = self._clock_seen
            return seen is None or seen < self.node.get_clock().now().nanoseconds
        timer = self._tick_timer
        if timer is None or timer.is_canceled():
            return False
        remaining = timer.time_until_next_call()
        return remaining is not None and remaining <= 0

    # ------------------------------------------------------------- setup
    def configure(self, was_publishing_clock: bool = False) -> None:
        """(Re)create the timers for the simulation's current settings."""
        node = self.node
        self._stop_thread(join=False)
        for timer in self._timers:
            node.destroy_timer(timer)
        self._timers.clear()
        self._tick_timer = None
        s = self.sim.settings
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        if s.publish_clock:
            if self._pub_clock is None:
                self._pub_clock = node.create_publisher(ClockMsg, "/clock", CLOCK_QOS)
            if self.sim.started:
                self.sim_ns = self.sim.t_ns  # continue from where the node's time base was
            self._anchor = (self.sim_ns, time.monotonic_ns())
            if s.real_time_factor > 0:
                period = s.tick_ns / s.real_time_factor / 1e9
                self._timers.append(node.create_timer(period, self._on_pace, clock=steady))
            else:  # as fast as possible (no guard conditions: the events executor lacks them)
                self._timers.append(node.create_timer(FREE_RUN_PERIOD_S, self._on_free_run, clock=steady))
        else:
            if was_publishing_clock:
                self.gaps.switched(self.sim.t_ns, "publish_clock", self.time_base())
                self.sim.stop()  # leaving our own time base: restart on the node clock at its next tick
            self._tick_timer = node.create_timer(s.tick_ns / 1e9, self._on_tick)
            self._timers.append(self._tick_timer)
        if s.publish_clock != (self._clock_sub is None):  # with publish_clock the node's own /clock is not heard
            if self._clock_sub is None:
                self._clock_sub = node.create_subscription(ClockMsg, "/clock", self._on_clock, CLOCK_TICK_QOS)
            else:
                node.destroy_subscription(self._clock_sub)
                self._clock_sub = None
        self.stats.prev_start = None

    def _stop_thread(self, join: bool) -> None:
        """Stop the tick thread; ``join`` (never while holding the lock): also wait for every thread
        stopped earlier without a join."""
        thread = self._thread
        if thread is not None:
            if thread.failure is None:
                self._thread = None
            thread.stop(join=join)
            if not join:
                self._retired.append(thread)
        if join:
            for old in self._retired:
                if not old.stop(join=True):
                    self.node.get_logger().warn("a stopped tick thread did not end within 10 s")
            self._retired = [old for old in self._retired if old.alive() or old.failure is not None]

    def _on_clock(self, msg) -> None:
        """A ``/clock`` message on simulated time: start the run, or tick if it reaches the grid's next point,
        or restart if it went back (see the module docstring)."""
        if self.sim.settings.publish_clock or not self.use_sim_time():
            return
        now = msg.clock.sec * 1_000_000_000 + msg.clock.nanosec
        with self.lock:
            self._clock_seen = now
            sim = self.sim
            t, tick_ns = sim.t_ns, sim.settings.tick_ns
            if t is not None and t <= now < next_tick_ns(t, sim.origin_ns, tick_ns):
                return  # the same tick (a repeated /clock, or one between two grid points)
            start = time.perf_counter()
            self.gaps.tick(t, now, tick_ns, "sim_time", "/clock" if t is not None else "first /clock")
            self._tick(now)
            if t is not None:
                self.stats.record(start, time.perf_counter(), None)

    def _on_clock_change(self, jump) -> None:
        """ROS time (de)activated (use_sim_time toggled): restart on the new time base.

        Back on the system clock the ticks resume within one period: the tick
        thread starts here (or the executor timer is reset to now + one
        period). Left to itself, the tick timer, created on the node's ROS
        clock, kept the schedule it had on simulated time, and the events
        executor first served it 2-20 s later: the node was silent meanwhile.
        """
        self._ros_time = None  # re-read on the next use
        with self.lock:
            if self._thread is not None:  # /clock ticks the node from now on
                self._stop_thread(join=False)
            if not self.sim.settings.publish_clock:
                new = self.time_base()
                self.gaps.switched(self.sim.t_ns, "system" if new == "sim_time" else "sim_time", new)
                self.sim.stop()
            timer = self._tick_timer
            if timer is None:
                return
            if not self.use_sim_time() and self.sim.settings.tick_thread and not self.sim.settings.publish_clock:
                timer.cancel()
                self._thread = TickThread(self)
                self._thread.start()
            else:
                timer.reset()

    def destroy(self) -> None:
        self._stop_thread(join=True)
        self.gaps.flush()  # short gaps still collected: to the recording before it closes
        for timer in self._timers:
            self.node.destroy_timer(timer)
        self._timers.clear()
        if self._clock_sub is not None:
            self.node.destroy_subscription(self._clock_sub)
            self._clock_sub = None

    # ------------------------------------------------------------- ticks
    def _on_tick(self) -> None:
        with self.lock:
            self._on_tick_locked()

    def _on_tick_locked(self) -> None:
        start = time.perf_counter()
        sim = self.sim
        if self.use_sim_time():  # /clock ticks the node (_on_clock): this timer rests until the system clock is back
            self._tick_timer.cancel()
            return
        if sim.settings.tick_thread:  # the thread ticks from now on; this timer rests until /clock takes over
            if self._thread is None:
                self._thread = TickThread(self)
                self._thread.start()
            self._tick_timer.cancel()
            return
        # the node's clock without /clock is the system clock (CLOCK_REALTIME), read here without rclpy's Time object
        now = time.time_ns()
        if sim.started:
            now = sim.grid_time(now)
        else:  # start on the time this call was scheduled for: later calls then land on the grid
            remaining = self._tick_timer.time_until_next_call()
            tick = sim.settings.tick_ns
            if remaining is not None and 0 <= tick - remaining <= tick:
                now = now + remaining - tick
            now -= now % SYSTEM_TIME_QUANTUM_NS
        self.gaps.tick(sim.t_ns, now, sim.settings.tick_ns, "system", "executor timer")
        self._tick(now)
        self.stats.record(start, time.perf_counter(), self.nominal_period())

    def _master_tick(self, target_ns: int, start: float, nominal: float | None) -> None:
        self.sim_ns = target_ns
        with self.lock:
            self.gaps.tick(self.sim.t_ns, target_ns, self.sim.settings.tick_ns, "publish_clock", "publish_clock")
            self._tick(target_ns)
            msg = self._clock_msg
            stamp(msg.clock, target_ns)
            self._pub_clock.publish(msg)
            self.stats.record(start, time.perf_counter(), nominal)

    def _on_pace(self) -> None:
        """publish_clock with real_time_factor > 0: simulated time follows the wall clock x factor."""
        start = time.perf_counter()
        s = self.sim.settings
        if not self.sim.started:  # the run starts at its time here (0), not at the wall time of this first call
            self._anchor = (self.sim_ns, time.monotonic_ns())
            self._master_tick(self.sim_ns, start, self.nominal_period())
            return
        anchor_sim, anchor_wall = self._anchor
        elapsed = int((time.monotonic_ns() - anchor_wall) * s.real_time_factor)
        target = anchor_sim + (elapsed // s.tick_ns) * s.tick_ns
        if target <= self.sim_ns:
            return
        due = (target - self.sim_ns) // s.tick_ns
        if target - self.sim_ns > MAX_CATCH_UP_NS:  # wall timer starved: re-anchor with one tick, do not burst (the
            self.stats.counters["late_ticks"] += 1  # master slows; no tick skipped)
            due = 1
            self._anchor = (self.sim_ns + s.tick_ns, time.monotonic_ns())
        nominal = self.nominal_period()
        for _ in range(due):  # each tick published with its /clock (one jump of several ticks skipped their outputs)
            self._master_tick(self.sim_ns + s.tick_ns, start, nominal)
            start = time.perf_counter()

    def _on_free_run(self) -> None:
        """publish_clock with real_time_factor = 0: whole ticks back to back for one slice of wall time.

        Between slices the executor serves inputs, services and parameters.
        """
        end = time.perf_counter() + FREE_RUN_SLICE_S
        tick_ns = self.sim.settings.tick_ns
        while True:
            start = time.perf_counter()
            target = self.sim_ns + tick_ns if self.sim.started else self.sim_ns
            self._master_tick(target, start, None)
            if start >= end:
                break
