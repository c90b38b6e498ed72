"""SIGINT/SIGTERM end every spin, whatever the main thread holds when they arrive.

A Python signal handler runs in the main thread between two bytecodes. rclpy's
``SingleThreadedExecutor`` takes its task-list lock several times per callback
it runs; a handler that completed an rclpy ``Future`` took the same lock and
deadlocked the process for good (a node once ignored SIGTERM in CI). The
tests run in child processes, so that a deadlock shows as a timeout instead of
hanging the suite.
"""

from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest

from belt_drive_ros.ros import environment as ros_env

pytestmark = pytest.mark.ros

CHILD = textwrap.dedent(
    """
    import _thread, os, signal, threading

    import rclpy.executors
    from belt_drive_ros.ros import executors
    from rclpy.node import Node

    # every lock rclpy makes from here on (its futures' and executors' locks) counts
    # the acquisitions made while a signal handler runs
    in_handler = [False]
    taken = []

    class CountingLock:
        def __init__(self):
            self._lock = _thread.allocate_lock()
        def acquire(self, blocking=True, timeout=-1):
            if in_handler[0]:
                taken.append(1)
            return self._lock.acquire(blocking, timeout)
        def release(self):
            self._lock.release()
        def locked(self):
            return self._lock.locked()
        __enter__ = acquire
        def __exit__(self, *exc):
            self.release()

    threading.Lock = CountingLock
    if hasattr(rclpy.executors, "Lock"):
        rclpy.executors.Lock = CountingLock

    installed = executors.stop_on_signals

    class watched:
        # stop_on_signals, with its SIGTERM handler flagged while it runs
        def __enter__(self):
            self.cm = installed()
            stop = self.cm.__enter__()
            handler = signal.getsignal(signal.SIGTERM)
            def flagged(signum, frame):
                in_handler[0] = True
                try:
                    handler(signum, frame)
                finally:
                    in_handler[0] = False
            signal.signal(signal.SIGTERM, flagged)
            return stop
        def __exit__(self, *exc):
            return self.cm.__exit__(*exc)

    executors.stop_on_signals = watched

    with executors.ros_session() as ctx:
        node = Node("signal_probe", context=ctx)
        node.create_timer(0.001, lambda: None)
        for kind in ("single", "events"):
            ex = executors.make_executor(ctx, kind)
            ex.add_node(node)
            threading.Timer(0.2, os.kill, (os.getpid(), signal.SIGTERM)).start()
            print(kind, executors.spin_until_signal(ex, ctx, poll=0.05, duration=30.0), len(taken), flush=True)
            ex.shutdown()
        node.destroy_node()
    """
)


def test_the_signal_handler_takes_no_lock_the_interrupted_main_thread_could_hold():
    """A handler that took a lock the main thread held when the signal came would wait forever."""
    env = ros_env.child_environment(ros_env.process_domain_id(offset=71))
    try:
        out = subprocess.run([sys.executable, "-c", CHILD], env=env, capture_output=True, text=True, timeout=60)
    except subprocess.TimeoutExpired as exc:
        pytest.fail(f"the spin did not end on SIGTERM:\n{exc.stderr}")
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split("\n")[:2] == ["single 15 0", "events 15 0"], out.stdout


def test_a_signal_ends_spin_until_signal_within_the_poll_period():
    """SIGTERM sent from another thread mid-spin: the spin returns its number within a poll or two."""
    code = textwrap.dedent(
        """
        import os, signal, threading, time
        from belt_drive_ros.ros.executors import make_executor, ros_session, spin_until_signal
        from rclpy.node import Node

        with ros_session() as ctx:
            node = Node("signal_probe", context=ctx)
            ticks = [0]
            node.create_timer(0.001, lambda: ticks.__setitem__(0, ticks[0] + 1))
            for kind in ("single", "events"):
                ex = make_executor(ctx, kind)
                ex.add_node(node)
                for delay in (0.03, 0.057, 0.2, 0.31):  # after the handler is in place
                    threading.Timer(delay, os.kill, (os.getpid(), signal.SIGTERM)).start()
                    t0 = time.monotonic()
                    sig = spin_until_signal(ex, ctx, poll=0.1, duration=30.0)
                    print(kind, sig, round(time.monotonic() - t0 - delay, 3), flush=True)
                ex.shutdown()
            print("ticks", ticks[0] > 100, flush=True)
            node.destroy_node()
        """
    )
    env = ros_env.child_environment(ros_env.process_domain_id(offset=72))
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    lines = out.stdout.split("\n")
    assert lines[-2] == "ticks True", out.stdout
    for line in lines[:-2]:
        kind, sig, late = line.split()
        assert int(sig) == 15, line
        assert float(late) < 0.5, line  # poll 0.1 s; 0.5 leaves room for a busy machine


def test_single_threaded_spin_keeps_no_callbacks_from_its_polls():
    """rclpy's single-threaded executor adds a done callback to the awaited future on every call.

    Polling 0.5 s at 1 ms must not leave thousands of them behind (a slow leak over a long run).
    """
    code = textwrap.dedent(
        """
        import gc, tracemalloc
        from belt_drive_ros.ros.executors import make_executor, ros_session, spin_until_signal
        from rclpy.node import Node

        with ros_session() as ctx:
            node = Node("leak_probe", context=ctx)
            node.create_timer(0.001, lambda: None)
            ex = make_executor(ctx, "single")
            ex.add_node(node)
            spin_until_signal(ex, ctx, poll=0.001, duration=0.2)  # warm-up
            gc.collect()
            tracemalloc.start()
            before = tracemalloc.get_traced_memory()[0]
            spin_until_signal(ex, ctx, poll=0.001, duration=0.5)
            gc.collect()
            print(tracemalloc.get_traced_memory()[0] - before, flush=True)
            ex.shutdown()
            node.destroy_node()
        """
    )
    env = ros_env.child_environment(ros_env.process_domain_id(offset=73))
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    grown = int(out.stdout.split()[-1])
    assert grown < 100_000, f"{grown} bytes kept by 500 polls"
