"""The README's node examples move the drive: node + ``belt-drive source``, or ``drive_source:=scene``; alone, it coasts.

Three processes sets run at once, each in a ROS domain of its own, for
10 s of wall time once every process runs, with the node recording (``--record``): the node of
``truck_compressor`` with ``belt-drive source engine --scene
truck_compressor`` (its diesel and governor: the README says ~78 rad/s),
the node with ``drive_source:=scene`` (no source), and the node alone
(drive_torque never arrives: 0 N m, it coasts down from its initial
73.3 rad/s under the compressor's load). Speeds are read from the
recordings.
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
    runs = {
        "source": [["node", "truck_compressor", "--record", "source.mcap"],
                   ["source", "engine", "--scene", "truck_compressor"]],
        "scene": [["node", "truck_compressor", "--record", "scene.mcap", "--ros-args", "-p", "drive_source:=scene"]],
        "alone": [["node", "truck_compressor", "--record", "alone.mcap"]],
    }
    procs = []
    for k, commands in enumerate(runs.values()):
        env = ros_env.child_environment(ros_env.process_domain_id(offset=70 + k))
        procs += [_start(args, env, tmp_path) for args in commands]
    kinds = [args[0] for commands in runs.values() for args in commands]
    try:
        # every process running before the clock starts (a loaded machine takes seconds to start one), then
        # 10 s of drive; a process that never says it runs fails below with its output
        deadline = time.monotonic() + 90.0
        while time.monotonic() < deadline and not all(
            any(RUNNING[kind] in line for line in list(proc.lines)) for kind, proc in zip(kinds, procs)
        ):
            assert all(proc.poll() is None for proc in procs), [proc.lines[-5:] for proc in procs]
            time.sleep(0.2)
        time.sleep(10.0)
    finally:
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

    t, w = _speed(tmp_path / "source.mcap")
    assert t[-1] - t[0] > 3.0, "the node recorded less than 3 s"
    late = w[t > t[-1] - 2.0]
    # The droop governor's set point is 77.5 rad/s (README: ~78). The loop closes over DDS in real time, so how
    # far the first swing overshoots and how soon it settles depend on the machine's load (a run on a loaded
    # machine was still coming down from 120 rad/s through 95 at the end): the test asserts the governed
    # band, forward rotation, not the settled value.
    assert 45.0 < late.mean() < 130.0 and late.min() > 0.0, (late.mean(), late.min())

    t, w = _speed(tmp_path / "scene.mcap")
    assert t[-1] - t[0] > 3.0 and w[t > t[-1] - 1.0].mean() > 50.0  # the scene's own diesel drives it

    t, w = _speed(tmp_path / "alone.mcap")
    assert w[0] == pytest.approx(73.3) and w[-1] < 0.5 * w[0]  # no torque: coasts down under the load
