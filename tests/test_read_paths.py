"""Every path a command reads is checked before ``open()`` (issue 24).

A FIFO nobody writes to blocks ``open()`` for reading forever: ``sim
--torque-bag FIFO`` and ``msg-tools info FIFO`` hung. Each command runs in a
child process with a timeout (a hang is a failure, not a stuck test run) and
must end with exit 2 and one error line naming what the path is. Names the OS
refuses (a component past 255 bytes, no slash in it) are bad input too: exit 2.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
GOLDEN = ROOT / "bags" / "engine_idle_golden.mcap"
TORQUE = ROOT / "bags" / "engine_idle_torque.mcap"
BELT_DRIVE = [sys.executable, "-m", "belt_drive_ros.cli"]
MSG_TOOLS = [sys.executable, "-m", "msg_tools"]


def _run(argv: list[str], timeout: float = 60.0) -> tuple[int, str]:
    try:
        out = subprocess.run(argv, capture_output=True, text=True, timeout=timeout, cwd=ROOT,
                             env={**os.environ, "MPLBACKEND": "Agg"})
    except subprocess.TimeoutExpired:
        pytest.fail(f"hung (no answer within {timeout} s): {' '.join(argv)[:200]}")
    return out.returncode, out.stderr


def _one_error_line(err: str, prog: str) -> str:
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith(f"{prog}: error:"), err
    return lines[0]


@pytest.fixture
def fifo(tmp_path):
    path = tmp_path / "x.mcap"
    os.mkfifo(path)  # nobody ever writes: open() for reading would block
    return str(path)


@pytest.mark.parametrize("command", [
    "sim paper --duration 0.1 --quiet --torque-bag {fifo}",
    "sim {fifo} --duration 0.1 --quiet",
    "sim paper --duration 0.1 --quiet --torque-bag /dev/zero",
    "source profile --csv {fifo}",
    "replay {fifo}",
    "urdf {fifo}",
])
def test_belt_drive_refuses_a_fifo_or_device_without_opening_it(fifo, command):
    code, err = _run(BELT_DRIVE + command.format(fifo=fifo).split())
    assert code == 2, err
    line = _one_error_line(err, "belt-drive")
    assert "FIFO" in line or "character device" in line, line


@pytest.mark.parametrize("command", [
    "info {fifo}",
    "info {fifo} --summary-only",
    "export {fifo} --topic /joint_states",
    "plot {fifo} --out {tmp}/x.png",
    "compare {fifo} {golden}",
    "compare {golden} {fifo}",
])
def test_msg_tools_refuses_a_fifo_without_opening_it(fifo, tmp_path, command):
    code, err = _run(MSG_TOOLS + command.format(fifo=fifo, golden=GOLDEN, tmp=tmp_path).split())
    assert code == 2, err
    assert "FIFO" in _one_error_line(err, "msg-tools")


def test_msg_tools_refuses_a_device(tmp_path):
    code, err = _run(MSG_TOOLS + ["info", "/dev/zero"])
    assert code == 2 and "character device" in _one_error_line(err, "msg-tools")


def test_a_fifo_inside_a_bag_folder_is_refused(tmp_path):
    folder = tmp_path / "run"
    folder.mkdir()
    os.mkfifo(folder / "run_0.mcap")
    code, err = _run(MSG_TOOLS + ["info", str(folder)])
    assert code == 2 and "FIFO" in _one_error_line(err, "msg-tools")


@pytest.mark.parametrize("name", ["a" * 300, "b" * 5000, "c" * 300 + ".yaml", "/".join(["d" * 200] * 30)])
def test_sim_refuses_names_the_os_refuses_as_bad_input(name):
    code, err = _run(BELT_DRIVE + ["sim", name, "--duration", "0.1", "--quiet"])
    assert code == 2, err
    line = _one_error_line(err, "belt-drive")
    assert len(line) < 500, line
