"""A ``belt-drive`` program started with its stderr closed (``2>&-``) keeps its errors off stdout.

Python then has ``sys.stderr`` None, and ``print(..., file=None)`` writes to stdout: the one-line error of a bad
scene went into the data stream of a pipeline (``belt-drive sim ... 2>&- | consumer``). The exit code carries the
failure; the message goes nowhere, as any tool's does with its stderr closed.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("args, code", [(["sim", "nosuch"], 2), (["sim", "paper", "--dt", "-1"], 2)])
def test_an_error_with_stderr_closed_is_not_written_to_stdout(tmp_path, args, code):
    sh = shutil.which("sh")
    cmd = " ".join([f'"{sys.executable}"', "-c", "'import sys; from belt_drive_ros.cli import main; sys.exit(main())'"]
                   + args) + " 2>&-"
    run = subprocess.run([sh, "-c", cmd], capture_output=True, text=True, cwd=tmp_path, timeout=300,
                         env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert run.returncode == code
    assert run.stdout == ""


def test_a_run_with_stderr_closed_still_prints_its_summary_on_stdout(tmp_path):
    cmd = f'"{sys.executable}" -c "import sys; from belt_drive_ros.cli import main; sys.exit(main())" sim paper --duration 0.01 2>&-'
    run = subprocess.run([shutil.which("sh"), "-c", cmd], capture_output=True, text=True, cwd=tmp_path, timeout=300,
                         env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert run.returncode == 0
    assert run.stdout.startswith("scene          paper")
