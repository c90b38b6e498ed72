"""The numerical core and the CLI's command modules import without rclpy.

Each check runs in a fresh interpreter: this pytest process has rclpy loaded
by other tests already.
"""

import subprocess
import sys

import pytest

CORE = ("params", "model", "integrators", "simulate", "scene", "sources", "stability", "fidelity", "ros_env")


def _imports_rclpy(code: str) -> list[str]:
    probe = code + "\nimport sys\nprint(sorted(m for m in sys.modules if m == 'rclpy' or m.startswith('rclpy.')))"
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    return eval(out.stdout.strip().splitlines()[-1])  # noqa: S307 - our own list literal


def test_core_modules_do_not_import_rclpy():
    code = "\n".join(f"import belt_drive_ros.{name}" for name in CORE)
    code += "\nfrom belt_drive_ros.simulate import simulate\nfrom belt_drive_ros.scene import load_scene\n"
    code += "simulate(load_scene('paper'), duration=0.01)"
    assert _imports_rclpy(code) == []


@pytest.mark.parametrize("command", ["node", "source", "demo"])
def test_ros_command_modules_import_rclpy_only_when_run(command):
    assert _imports_rclpy(f"import belt_drive_ros.commands.{command}") == []


def test_cli_parser_does_not_import_rclpy():
    assert _imports_rclpy("from belt_drive_ros.cli import build_parser\nbuild_parser()") == []
