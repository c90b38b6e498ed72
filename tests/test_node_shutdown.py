"""SIGINT and SIGTERM stop ``belt-drive node`` in every mode the README shows, with its recording finished.

Each mode runs as a child process (the CLI, Fast DDS over UDP only: a child
killed after a failure leaves nothing in /dev/shm) on a domain private to this
test, records with ``--record``, and gets a signal once it ticks. It must exit
with 0 within 2 s, and its recording must read back complete (a summary
section that agrees with the data). With ``publish_clock`` at
``real_time_factor:=0`` the events executor never ran out of work, its spin
never returned, and both signals were ignored until SIGKILL.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import threading
import time

import pytest

from belt_drive_ros.ros import environment as ros_env

pytestmark = pytest.mark.ros

CLI = [sys.executable, "-m", "belt_drive_ros.cli"]
#: /clock of the mode that follows a clock publisher starts here (as `belt-drive replay --clock` of a shipped bag)
CLOCK_START_NS = 1_767_225_600 * 1_000_000_000

MODES = {
    "wall-clock": [],
    "sim-time-no-clock": ["-p", "use_sim_time:=true"],
    "sim-time-clock": ["-p", "use_sim_time:=true"],
    "publish-clock-rtf0": ["-p", "publish_clock:=true", "-p", "real_time_factor:=0"],
    "publish-clock-rtf1": ["-p", "publish_clock:=true", "-p", "real_time_factor:=1"],
}


class Child:
    """``belt-drive node paper --record PATH`` with its stderr collected by a thread."""

    def __init__(self, ros_args, record, domain):
        self.proc = subprocess.Popen(
            CLI + ["node", "paper", "--record", str(record), "--ros-args", *ros_args],
            env=ros_env.child_environment(domain), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
        )
        self.lines: list[str] = []
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self):
        for line in self.proc.stderr:
            self.lines.append(line)

    def wait_for(self, text, timeout=60.0):
        deadline = time.monotonic() + timeout
        while not any(text in line for line in self.lines):
            if self.proc.poll() is not None:
                self._reader.join(5.0)
                pytest.fail(f"child exited ({self.proc.returncode}) before {text!r}:\n{''.join(self.lines)[-3000:]}")
            if time.monotonic() > deadline:
                self.kill()
                pytest.fail(f"child did not log {text!r} within {timeout} s:\n{''.join(self.lines)[-3000:]}")
            time.sleep(0.05)

    def stop(self, sig, within=2.0):
        """Send ``sig``; the exit code and the seconds until the exit (None: killed after ``within`` s)."""
        start = time.monotonic()
        self.proc.send_signal(sig)
        try:
            rc = self.proc.wait(timeout=within)
        except subprocess.TimeoutExpired:
            self.kill()
            return None, None
        self._reader.join(5.0)
        return rc, time.monotonic() - start

    def kill(self):
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()


class ClockPublisher:
    """/clock on ``domain`` from this process: 1 ms of simulated time every 2 ms, from CLOCK_START_NS."""

    def __init__(self, domain):
        import rclpy
        from rclpy.context import Context
        from rosgraph_msgs.msg import Clock

        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain)
        self.node = rclpy.create_node(f"test_clock_{domain}", context=self.context)
        self.pub = self.node.create_publisher(Clock, "/clock", 10)
        self.msg = Clock()
        self.done = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self):
        t = CLOCK_START_NS
        while not self.done.wait(0.002):
            self.msg.clock.sec, self.msg.clock.nanosec = divmod(t, 1_000_000_000)
            self.pub.publish(self.msg)
            t += 1_000_000

    def close(self):
        import rclpy

        self.done.set()
        self.thread.join(5.0)
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


@pytest.mark.parametrize("mode", list(MODES))
def test_node_exits_on_sigint_and_sigterm_with_its_recording_finished(mode, tmp_path):
    from msg_tools import summary

    offset = 60 + 2 * list(MODES).index(mode)
    signals = {signal.SIGINT: ros_env.process_domain_id(offset=offset),
               signal.SIGTERM: ros_env.process_domain_id(offset=offset + 1)}
    children, clocks = {}, []
    try:
        for sig, domain in signals.items():
            children[sig] = Child(MODES[mode], tmp_path / f"{sig.name}.mcap", domain)
            if mode == "sim-time-clock":
                clocks.append(ClockPublisher(domain))
        for child in children.values():
            child.wait_for("spinning with the")
        for clock in clocks:  # the node has discovered the /clock publisher (it ticks from then on)
            deadline = time.monotonic() + 60.0
            while clock.pub.get_subscription_count() < 1 and time.monotonic() < deadline:
                time.sleep(0.05)
        time.sleep(1.5)  # ticking (or, on /clock with no publisher, waiting) for a while
        results = {sig: child.stop(sig) for sig, child in children.items()}
    finally:
        for child in children.values():
            child.kill()
        for clock in clocks:
            clock.close()
    for sig, (rc, seconds) in results.items():
        err = "".join(children[sig].lines)[-3000:]
        assert rc is not None, f"{mode}: still running 2 s after {sig.name}:\n{err}"
        assert rc == 0, f"{mode}: exit code {rc} after {sig.name}:\n{err}"
        assert f"shutting down (signal {int(sig)})" in err
        assert "Traceback" not in err
        info = summary(tmp_path / f"{sig.name}.mcap")  # the data checked against the summary section
        assert info.complete and info.verified and not info.damage, (info.stop_reason, info.damage)
        counts = {t.topic: t.message_count for t in info.topics}
        assert counts["/robot_description"] == 1
        if mode != "sim-time-no-clock":
            assert counts["/shaft_speed"] > 0
        if mode == "sim-time-clock":  # every message on the /clock time base, latched ones included
            assert info.start_ns >= CLOCK_START_NS
            assert info.end_ns - info.start_ns < 60e9
