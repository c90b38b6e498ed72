"""The README's node examples move the drive: node + ``belt-drive source``, or ``drive_source:=scene``; alone, it coasts.

Three process sets run at once, each in a ROS domain of its own, with the
node recording (``--record``): the node of ``truck_compressor`` with
``belt-drive source engine --scene truck_compressor`` (its diesel and
governor: the README says ~78 rad/s), the node with ``drive_source:=scene``
(no source), and the node alone (drive_torque never arrives: 0 N m, it
coasts down from its initial 73.3 rad/s under the compressor's load).
Speeds are read from the recordings.

The last two run 10 s of wall time. The node and its source close a loop
between two processes; on the wall clock a loaded machine starves them in
turn and the node holds a firing pulse's torque for as long as the source is
starved, so they run the README's commands with ``use_sim_time:=true`` on
``/clock`` stepped by the test once both have answered each tick
(``test_node_process``'s :meth:`Probe.lockstep`): what they do no longer
depends on the machine's load.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from belt_drive_ros.ros import environment as ros_env
from msg_tools import read_topic
from test_node_process import LOOP_START_NS, LOOP_TICK_NS, LOOP_TICKS, Probe, check_governed_loop, loop_ready

BIN = Path(sys.executable).parent

pytestmark = [pytest.mark.ros, pytest.mark.slow]


def _start(args, env, cwd):
    """The command with its output collected line by line (``proc.lines``) by a reader thread."""
    proc = subprocess.Popen([str(BIN / "belt-drive"), *args], env=env, cwd=cwd, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    proc.lines = []
    proc.reader = threading.Thread(target=lambda: proc.lines.extend(iter(proc.stdout.readline, "")), daemon=True)
    proc.reader.start()
    return proc


#: a line each command prints once it runs (the node: its scene and model; the source: what it publishes)
RUNNING = {"node": "model ", "source": "publishing drive_torque"}


def _speed(path: Path) -> tuple[np.ndarray, np.ndarray]:
    data = read_topic(path, "/shaft_speed")
    return (data.log_time_ns - data.log_time_ns[0]) * 1e-9, np.asarray(data.fields["data"], dtype=float)


def test_readme_node_examples_move_the_drive(tmp_path):
    sim_time = ["--ros-args", "-p", "use_sim_time:=true"]
    runs = {
        "source": [["node", "truck_compressor", "--record", "source.mcap", *sim_time],
                   ["source", "engine", "--scene", "truck_compressor", *sim_time]],
        "scene": [["node", "truck_compressor", "--record", "scene.mcap", "--ros-args", "-p", "drive_source:=scene"]],
        "alone": [["node", "truck_compressor", "--record", "alone.mcap"]],
    }
    procs = []
    for k, commands in enumerate(runs.values()):
        env = ros_env.child_environment(ros_env.process_domain_id(offset=70 + k))
        procs += [_start(args, env, tmp_path) for args in commands]
    kinds = [args[0] for commands in runs.values() for args in commands]
    probe = None
    try:
        # every process running before the clock starts (a loaded machine takes seconds to start one), then
        # 10 s of drive; a process that never says it runs fails below with its output
        deadline = time.monotonic() + 90.0
        while time.monotonic() < deadline and not all(
            any(RUNNING[kind] in line for line in list(proc.lines)) for kind, proc in zip(kinds, procs)
        ):
            assert all(proc.poll() is None for proc in procs), [proc.lines[-5:] for proc in procs]
            time.sleep(0.2)
        end = time.monotonic() + 10.0
        probe = Probe(ros_env.process_domain_id(offset=70))
        probe.spin_until(lambda: loop_ready(probe), 60.0, "the node and the source to discover each other", procs[:2])
        probe.lockstep(LOOP_START_NS, LOOP_TICK_NS, LOOP_TICKS, procs[:2])
        time.sleep(max(0.0, end - time.monotonic()))
    finally:
        if probe is not None:
            probe.close()
        for proc in procs:
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
        for proc in procs:
            try:
                proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
            proc.reader.join(timeout=5)
    outputs = ["".join(proc.lines) for proc in procs]
    assert all(p.returncode == 0 for p in procs), "\n".join(o[-800:] for o in outputs)

    # the README's ~78 rad/s: the loop follows the scene's own diesel offline (the node's ticks: scene time
    # 0 is the first /clock), applying the torques the source published
    source = tmp_path / "source.mcap"
    t, w = _speed(source)
    assert t[-1] == pytest.approx((LOOP_TICKS - 1) * LOOP_TICK_NS / 1e9) and np.allclose(np.diff(t[-200:]), 1e-3)
    applied = np.asarray(read_topic(source, "/drive_torque_applied").fields["data"], dtype=float)
    check_governed_loop(w, applied, read_topic(source, "/drive_torque").fields["data"])

    t, w = _speed(tmp_path / "scene.mcap")
    assert t[-1] - t[0] > 3.0 and w[t > t[-1] - 1.0].mean() > 50.0  # the scene's own diesel drives it

    t, w = _speed(tmp_path / "alone.mcap")
    assert w[0] == pytest.approx(73.3) and w[-1] < 0.5 * w[0]  # no torque: coasts down under the load
