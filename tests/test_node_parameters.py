"""The node's parameter schema without ROS: --list-parameters, ranges from the core's rules, settings."""

from __future__ import annotations

import math
import subprocess
import sys

import pytest

from belt_drive_ros.core.errors import ParameterError
from belt_drive_ros.core.params import FIELD_DOCS, BeltDriveParams
from belt_drive_ros.core.scene import load_scene
from belt_drive_ros.ros.parameter_schema import (
    MODEL_PARAMETERS,
    NodeConfigError,
    build_settings,
    default_values,
    model_range,
    scene_torque_bound,
)


def test_list_parameters_runs_without_rclpy():
    """In a fresh interpreter: the CLI prints every parameter and never imports rclpy."""
    code = (
        "import sys\nfrom belt_drive_ros.cli import main\nrc = main(['node', '--list-parameters'])\n"
        "print('RCLPY', sorted(m for m in sys.modules if m.split('.')[0] in ('rclpy', 'rcl_interfaces')))\n"
        "raise SystemExit(rc)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().splitlines()[-1] == "RCLPY []"
    for name in ("step_rate_hz", "torque_bound", "record_path", *FIELD_DOCS):
        assert f"  {name} " in out.stdout, name


@pytest.mark.parametrize("name", MODEL_PARAMETERS)
def test_model_ranges_are_the_core_rules(name):
    """Inside the advertised range BeltDriveParams accepts; just outside it refuses (each end)."""
    lo, hi = model_range(name)
    base = BeltDriveParams().field_values()
    assert lo == 0.0 and math.isfinite(hi) and hi >= base[name]  # groove_angle: the flat belt (pi) is both default and upper end
    BeltDriveParams(**{**base, name: hi})  # the upper end itself is valid
    with pytest.raises(ParameterError, match=name):
        BeltDriveParams(**{**base, name: -1e-9})
    values = default_values(load_scene("paper"))
    with pytest.raises(NodeConfigError, match=name):
        build_settings({**values, name: hi * 1.0001})


def test_torque_bound_is_derived_from_the_scene_or_set():
    scene = load_scene("paper")
    values = default_values(scene)
    derived = build_settings(values).torque_bound
    assert derived == scene_torque_bound(scene) >= 10.0 * max(abs(scene.load.torque(0.0, 0.0, 0.0)), 1e-3)
    assert build_settings({**values, "torque_bound": 50.0}).torque_bound == 50.0
