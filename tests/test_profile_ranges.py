"""Profile fields from outside have plausible ranges (issue 13, item 6: absurd values in scenes).

Every field a profile class lists in ``PLAUSIBLE`` is tried ten times beyond its range in a
mapping that is otherwise valid -- the class constructor accepts it (idealised values stay
possible in code) -- and :func:`make_profile` (the path of scene files, recordings' scenes
and campaigns) refuses it naming the field and the range. Counts (harmonics, cylinders,
schedule periods) have limits too; the shipped scenes stay valid; through ``belt-drive sim``
an absurd torque is one line, exit 2.
"""

from __future__ import annotations

import numpy as np
import pytest

from belt_drive_ros.cli import main
from belt_drive_ros.core.errors import SceneError
from belt_drive_ros.io.scenes import load_scene
from belt_drive_ros.core.scene import shipped_scenes
from belt_drive_ros.core.sources import _KINDS, _REGISTRY, COUNT_MAX, TORQUE_MAX, make_profile

#: a valid mapping of each kind to start from (the class defaults, a motor curve given)
BASE = {kind: {"type": kind} for kind in _REGISTRY}
BASE["motor"] = {"type": "motor", "curve": [[0.0, 10.0], [100.0, 0.0]]}
BASE["schedule"] = {"type": "schedule", "active": 1.0, "inactive": 0.0, "periods": [[0.0, 1.0]]}
BASE["engine"] = {"type": "engine", "speed_setpoint": 100.0}

CASES = [(kind, key) for kind, cls in sorted(_REGISTRY.items()) for key in cls.PLAUSIBLE]


def _beyond(kind: str, key: str):
    """Mappings of ``kind`` with ``key`` ten times beyond its plausible magnitude (+ and -)."""
    cls = _REGISTRY[kind]
    top = _KINDS[cls.PLAUSIBLE[key]][0] * 10.0
    name, _, column = key.partition("[")
    out = []
    for value in (top, -top):
        spec = dict(BASE[kind])
        if column:  # a column of the motor curve: its last point
            j = int(column.rstrip("]"))
            curve = [list(p) for p in spec["curve"]]
            curve[-1][j] = value if j == 1 else abs(value)
            spec[name] = curve
        elif name == "periods":
            spec[name] = [[0.0, abs(value)]]
        elif name == "times":
            spec.update(times=[0.0, abs(value)], values=[0.0, 0.0])
        elif name in ("harmonics", "values"):
            spec[name] = [value] if name == "harmonics" else [0.0, value]
            if name == "values":
                spec["times"] = [0.0, 1.0]
        elif kind == "ramp" and name == "end_time":
            spec[name] = abs(value)
        elif kind == "ramp" and name == "start_time":
            spec[name] = -abs(value)
        else:
            spec[name] = value
        out.append(spec)
    return out


def _constructs(spec) -> bool:
    fields = {k: (tuple(tuple(v) if isinstance(v, list) else v for v in x) if isinstance(x, list) else x)
              for k, x in spec.items() if k != "type"}
    try:
        _REGISTRY[spec["type"]](**fields)
        return True
    except (SceneError, TypeError, ValueError):
        return False


@pytest.mark.parametrize("kind,key", CASES)
def test_every_profile_field_beyond_its_plausible_range_is_refused_by_name(kind, key):
    specs = [s for s in _beyond(kind, key) if _constructs(s)]
    assert specs, f"{kind}.{key}: no otherwise valid mapping beyond the range"
    for spec in specs:
        with pytest.raises(SceneError) as info:
            make_profile(spec, "drive")
        message = str(info.value)
        assert f"{key}" in message and "plausible range" in message, message
    make_profile(BASE[kind], "drive")  # the base itself is valid


@pytest.mark.parametrize("name,limit", sorted(COUNT_MAX.items()))
def test_counts_beyond_their_limit_are_refused(name, limit):
    spec = {"cylinders": {"type": "engine", "cylinders": limit + 1},
            "harmonics": {"type": "compressor", "harmonics": [1.0] * (limit + 1)},
            "periods": {"type": "schedule", "active": 1.0,
                        "periods": [[2.0 * k, 2.0 * k + 1.0] for k in range(limit + 1)]}}[name]
    with pytest.raises(SceneError, match=f"{name}: {limit + 1} is more than the plausible {limit}"):
        make_profile(spec, "load")
    make_profile({**spec, name: spec[name][:limit] if isinstance(spec[name], list) else limit}, "load")


def test_a_plain_number_and_nested_schedule_profiles_are_checked_too():
    with pytest.raises(SceneError, match="drive.value: 2e\\+06 N m is outside"):
        make_profile(2.0 * TORQUE_MAX, "drive")
    with pytest.raises(SceneError, match="active.*plausible range"):
        make_profile({"type": "schedule", "active": {"type": "sine", "amplitude": 1e300}, "periods": [[0, 1]]}, "load")
    assert make_profile(TORQUE_MAX, "drive").value == TORQUE_MAX  # the bound itself is plausible


@pytest.mark.parametrize("name", shipped_scenes())
def test_shipped_scenes_are_within_the_ranges(name):
    scene = load_scene(name)
    assert make_profile(scene.drive.to_dict(), "drive") == scene.drive
    assert make_profile(scene.load.to_dict(), "load") == scene.load


def test_an_absurd_torque_in_a_scene_file_is_one_line_exit_2(tmp_path, capsys):
    path = tmp_path / "absurd.yaml"
    path.write_text("extends: paper\ndrive: {type: sine, mean: 1.0, amplitude: 1.0e12, frequency: 5.0}\n")
    assert main(["sim", str(path), "--quiet", "--duration", "0.01"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("belt-drive: error: ") and "drive.amplitude" in err[0], err


@pytest.mark.parametrize("big", [10**400, 10**5000], ids=["400-digits", "5001-digits"])
def test_integers_beyond_the_float_range_are_one_scene_error_not_a_traceback(big):
    """Python callers can pass integers no float holds (YAML stops them at 2^63): a profile, the
    parameters and a network scene each refuse them naming the field (before: OverflowError, or
    for 5000 digits the ValueError of int-to-str conversion from the message itself)."""
    from belt_drive_ros.core.errors import ParameterError
    from belt_drive_ros.core.network.scene import NetworkScene
    from belt_drive_ros.core.params import BeltDriveParams

    with pytest.raises(SceneError, match="drive.value: must be finite, got an integer beyond 2\\^63"):
        make_profile(big, "drive")
    with pytest.raises(SceneError, match="drive.final: must be finite, got an integer beyond 2\\^63"):
        make_profile({"type": "step", "final": big, "time": 1.0}, "drive")
    with pytest.raises(ParameterError, match="I_M.*must be finite"):
        BeltDriveParams(I_M=big)
    data = {"kind": "network", "duration": 2e-3, "dt": 1e-3, "initial_speed": 1.0,
            "belt": {"EA": 1000.0, "damping": 0.1, "mass_per_length": big},
            "pulleys": [{"name": "a", "role": "driver", "centre": [0, 0], "radius": 0.05, "inertia": 1e-3, "torque": 0.1},
                        {"name": "b", "role": "accessory", "centre": [0.3, 0], "radius": 0.05, "inertia": 1e-3, "torque": 0.1}]}
    with pytest.raises(SceneError, match="belt.mass_per_length: must be finite"):
        NetworkScene.from_mapping(data)


@pytest.mark.parametrize("spec, message", [
    (float("inf"), "must be finite, got inf"),
    ({"type": ["a"]}, "drive.type: unknown profile \\['a'\\]"),
    ({"type": {"k": 1}}, "drive.type: unknown profile"),
    ({"type": "constant", "value": np.array([1.0])}, "drive.value: must be a number, got ndarray"),
    ({"type": "engine", "cylinders": np.zeros(2)}, "drive.cylinders: must be a number, got ndarray"),
])  # fmt: skip
def test_a_non_finite_number_or_an_unhashable_type_is_one_scene_error(spec, message):
    """An infinite float is named as such (not as a huge integer), a list or mapping as a profile's
    ``type`` is an unknown profile (before: TypeError, unhashable type), and an array where a number
    belongs is refused (before: accepted, then a TypeError in the run's encoding)."""
    with pytest.raises(SceneError, match=message):
        make_profile(spec, "drive")
