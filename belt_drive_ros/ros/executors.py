"""One way to start, spin and stop rclpy for every long-running command.

:func:`ros_session` initialises a private rclpy ``Context`` (loopback
discovery, no rclpy signal handlers), yields it, and always shuts it down;
:func:`spin_nodes` runs nodes on one executor until SIGINT/SIGTERM (or a
deadline, or a predicate) and then destroys them. ``belt-drive node``,
``source``, ``demo``, ``record`` and ``replay`` all go through these two.

Measured pitfalls they encode (ROS 2 Jazzy wheels):

* the ``EventsExecutor`` runs no callbacks when spun from a background
  thread: spin from the main thread;
* ``shutdown()`` from inside a callback hangs the events executor: signal
  handlers only complete a future, and shutdown happens after the spin
  returns;
* a signal arriving while no callback runs waits for the interpreter:
  the spin polls every ``poll`` seconds;
* a Python signal handler runs in the main thread between two bytecodes,
  possibly while that thread holds one of the ``threading.Lock`` objects
  rclpy takes on every spin (the executor's task list, a ``Future``'s
  state): a handler that completes a ``Future`` takes both and can
  deadlock the process for good (seen once in CI: a node ignored SIGTERM).
  The handler here only stores the signal number (:class:`StopSignal`);
* ``SingleThreadedExecutor.spin_until_future_complete`` adds a done
  callback to the future on every call and never removes it: the spin
  waits on a fresh future per poll, so nothing accumulates over a long run;
* the ``EventsExecutor`` (rclpy 7.1, its ``EventsQueue::RunUntil``) checks a
  spin's timeout only when its event queue is empty: a timer whose callback
  outlasts its period (``publish_clock`` at ``real_time_factor:=0``, a
  1 kHz tick timer on an overloaded machine) keeps the queue non-empty, the
  spin never returns to the poll, and SIGINT/SIGTERM were recorded but never
  acted on. :class:`SpinDeadline` completes each spin's future from a thread
  of its own at the spin's deadline (a queue stop, thread-safe), so every
  spin ends within ``poll`` however busy the executor is.
"""

from __future__ import annotations

import contextlib
import signal
import threading
import time
from contextlib import contextmanager
from typing import Callable, Iterable, Iterator, Sequence

from . import environment as ros_env

ros_env.configure_environment()  # discovery: the user's environment wins (see ros/environment.py), before any context starts

import rclpy  # noqa: E402
from rclpy.context import Context  # noqa: E402
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor  # noqa: E402
from rclpy.signals import SignalHandlerOptions  # noqa: E402
from rclpy.task import Future  # noqa: E402

__all__ = [
    "EXECUTORS",
    "SpinDeadline",
    "StopSignal",
    "executor_name",
    "make_executor",
    "ros_session",
    "spin_nodes",
    "spin_until",
    "spin_until_signal",
    "stop_on_signals",
]

EXECUTORS = ("auto", "events", "single")


def make_executor(context=None, kind: str = "auto"):
    """Executor for ``context``: ``events`` (rclpy.experimental.EventsExecutor), ``single`` or ``auto``.

    ``auto`` takes the events executor where this rclpy has it and falls back
    to ``SingleThreadedExecutor``. Spin either from the main thread (the
    events executor ran no callbacks when spun from a background thread in
    the Jazzy wheels). Measured at 1 kHz: events ~998 Hz at ~24 % CPU,
    single-threaded ~992 Hz at ~77 %, multi-threaded collapses (11-40 Hz).
    Lockstep drivers (:mod:`belt_drive_ros.ros.harness`) need ``single``.
    """
    if kind not in EXECUTORS:
        raise ValueError(f"executor: must be auto, events or single, got {kind!r}")
    if kind in ("auto", "events"):
        try:
            from rclpy.experimental import EventsExecutor
        except ImportError:
            if kind == "events":
                raise
        else:
            return EventsExecutor(context=context)
    return SingleThreadedExecutor(context=context)


def executor_name(executor) -> str:
    """Short name of an executor made by :func:`make_executor`."""
    return "single" if isinstance(executor, SingleThreadedExecutor) else "events"


def spin_until(executor, predicate: Callable[[], bool], timeout: float, step: float = 0.01) -> bool:
    """Spin ``executor`` one callback at a time until ``predicate()`` or ``timeout`` [s] of wall time."""
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            return False
        executor.spin_once(timeout_sec=step)
    return True


class StopSignal:
    """The first SIGINT/SIGTERM a process received, recorded without taking any lock.

    ``done()`` is True once a signal came; ``result()`` is its number (0
    before). The handler that sets it runs between two bytecodes of the main
    thread, whatever that thread holds, so it only assigns an attribute.
    While ``starting`` (a program building its nodes and outputs, before its
    spin), a second signal raises ``KeyboardInterrupt`` (the start-up is
    taking too long for the user: end it now); the first only asks the spin
    not to begin, so what the start-up opened (a recording) is closed whole.
    """

    __slots__ = ("signum", "starting")

    def __init__(self) -> None:
        self.signum = 0
        self.starting = False

    def done(self) -> bool:
        return self.signum != 0

    def result(self) -> int:
        return self.signum

    def handle(self, signum, frame=None) -> None:
        """Signal handler: keeps the first signal number (a second one while starting: KeyboardInterrupt)."""
        if not self.signum:
            self.signum = int(signum)
        elif self.starting:
            raise KeyboardInterrupt


@contextmanager
def stop_on_signals(starting: bool = False) -> Iterator[StopSignal]:
    """A :class:`StopSignal` that SIGINT/SIGTERM set (the previous handlers are restored on exit); ``starting``: its
    flag (a program that installs it before building its nodes: a signal there is not lost, nor does it kill the
    process with a recording half written; the program clears the flag once it spins)."""
    stop = StopSignal()
    stop.starting = starting
    on_signal = stop.handle

    previous = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield stop
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


class SpinDeadline:
    """Ends each spin at its deadline from a thread, even when the executor never runs out of work.

    ``arm(future, timeout)`` before a spin on ``future``: once ``timeout`` [s]
    has passed the thread completes the future (if the spin has not ended),
    which stops the executor after the callback it is running (the events
    executor's done callback stops its queue; the single-threaded one is
    woken). Only this thread and the spinning one take its lock; a signal
    handler never does. ``close()`` ends the thread.
    """

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._armed: tuple | None = None  # (future, deadline [s, monotonic])
        self._closed = False
        self._thread = threading.Thread(target=self._run, name="belt_drive_spin_deadline", daemon=True)
        self._thread.start()

    def arm(self, future: Future, timeout: float) -> None:
        with self._cond:
            self._armed = (future, time.monotonic() + timeout)
            self._cond.notify()

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._armed = None
            self._cond.notify()
        self._thread.join(timeout=5.0)

    def _run(self) -> None:
        while True:
            with self._cond:
                while not self._closed:
                    if self._armed is None:
                        self._cond.wait()
                        continue
                    left = self._armed[1] - time.monotonic()
                    if left <= 0:
                        break
                    self._cond.wait(left)
                if self._closed:
                    return
                future, self._armed = self._armed[0], None
            if not future.done():  # outside the lock: the done callbacks run here
                try:
                    future.set_result(None)
                except Exception:  # noqa: BLE001 - a future completed meanwhile, a dying executor
                    pass


def spin_until_signal(
    executor,
    context=None,
    poll: float = 0.25,
    duration: float | None = None,
    until: Callable[[], bool] | None = None,
    every: Callable[[], None] | None = None,
    stop: StopSignal | None = None,
) -> int:
    """Spin ``executor`` from the main thread until SIGINT/SIGTERM or context shutdown.

    Parameters
    ----------
    executor
        Made by :func:`make_executor`.
    context : rclpy Context, optional
        Default: rclpy's default context.
    poll : float
        [s] longest wait between a signal and the end of the spin (the
        handler wakes nothing: see the module notes), and the period of
        ``every``.
    duration : float, optional
        Stop after this many wall seconds.
    until : callable, optional
        Stop as soon as it returns True (checked every ``poll``).
    every : callable, optional
        Called every ``poll`` seconds between spins (e.g. topic discovery).
    stop : StopSignal, optional
        Installed by the caller (:func:`stop_on_signals`, before its start-up):
        a signal that came already ends the spin before it begins. Default:
        handlers installed here for the spin.

    Returns
    -------
    int
        The signal number, or 0 if the spin ended otherwise.
    """
    context = context or rclpy.get_default_context()
    end = None if duration is None else time.monotonic() + duration
    deadline = SpinDeadline()
    with (contextlib.nullcontext(stop) if stop is not None else stop_on_signals()) as stop:
        stop.starting = False  # (the spin: a second signal changes nothing)
        try:
            while not stop.done() and context.ok():
                if until is not None and until():
                    break
                if every is not None:
                    every()
                timeout = poll if end is None else min(poll, end - time.monotonic())
                if timeout <= 0:
                    break
                # a fresh future, completed at the deadline only: the executor's done callbacks die with it
                future = Future()
                deadline.arm(future, timeout)
                executor.spin_until_future_complete(future, timeout_sec=timeout)
        except (KeyboardInterrupt, ExternalShutdownException):
            pass
        finally:
            deadline.close()
    return stop.result()


@contextmanager
def ros_session(args: Sequence[str] | None = None, *, domain_id: int | None = None) -> Iterator[Context]:
    """A fresh rclpy ``Context`` for one command: initialised here, always shut down on exit.

    ``args`` are the process's ROS arguments (``["prog", "--ros-args", ...]``);
    rclpy installs no signal handlers (:func:`spin_until_signal` handles
    SIGINT/SIGTERM). BLAS runs single-threaded in the process
    (:func:`~belt_drive_ros.ros.environment.limit_blas_threads`), and the
    threads rclpy starts sleep without timer slack
    (:func:`~belt_drive_ros.ros.environment.reduce_timer_slack`: ticks wake on time).
    """
    ros_env.configure_environment()
    ros_env.limit_blas_threads()
    ros_env.reduce_timer_slack()
    context = Context()
    kwargs = {} if domain_id is None else {"domain_id": int(domain_id)}
    rclpy.init(args=list(args) if args else None, context=context,
               signal_handler_options=SignalHandlerOptions.NO, **kwargs)
    try:
        yield context
    finally:
        rclpy.try_shutdown(context=context)


def destroy(executor=None, nodes: Iterable = ()) -> None:
    """Shut ``executor`` down and destroy ``nodes`` (last first), ignoring errors of a dying context."""
    if executor is not None:
        try:
            executor.shutdown()
        except Exception:  # noqa: BLE001 - shutting down anyway
            pass
    for node in reversed(list(nodes)):
        try:
            node.destroy_node()
        except Exception:  # noqa: BLE001
            pass


def spin_nodes(nodes: Sequence, context, *, executor: str = "auto", freeze_gc: bool = True,
               started: Callable[[object], None] | None = None,
               stopped: Callable[[int], None] | None = None, **spin) -> int:
    """Spin ``nodes`` on one executor until a signal (see :func:`spin_until_signal`), then destroy them.

    ``freeze_gc`` moves every object alive at start (rclpy, numpy, scipy,
    the nodes) out of the garbage collector's scans: later collections only
    look at what the run allocates, so their pauses stay short. ``started``
    is called with the executor before the spin, ``stopped`` with the
    signal number after it (the nodes still exist). Returns the signal
    number (0 otherwise).
    """
    import gc

    ex = make_executor(context, executor)
    try:
        for node in nodes:
            ex.add_node(node)
        if started is not None:
            started(ex)
        if freeze_gc:
            gc.collect()
            gc.freeze()
        signum = spin_until_signal(ex, context, **spin)
        if stopped is not None:
            stopped(signum)
        return signum
    finally:
        destroy(ex, nodes)
        if freeze_gc:
            gc.unfreeze()
