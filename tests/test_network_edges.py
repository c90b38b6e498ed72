"""Belt networks at their edges: names that would share a topic, the pulley count, which pulley reaches its capstan
limit first, the hub load with centrifugal tension, the printed spring preload, the modes' operating point and the
accuracy guard's floor (the scene helpers are tests/test_network.py's)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from belt_drive_ros.core.errors import SceneError
from belt_drive_ros.core.network.model import NetworkModel
from belt_drive_ros.core.network.scene import NetworkScene
from belt_drive_ros.core.network.simulate import simulate
from belt_drive_ros.io.scenes import load_network
from test_network import _pulley, _scene
from test_network_runs import _two_pulleys



def test_names_that_would_share_a_topic_are_refused():
    """Span names join the pulley names with _: pulleys a, b_c, a_b, c would give two spans a_b_c (one CSV column and
    topic, alternating between two tensions), and a pulley named tensioner_arm the arm's own joint and topic."""
    square = [_pulley("a", (0.0, 0.0), 0.05, role="driver", torque=0.1), _pulley("b_c", (0.3, 0.0), 0.05, role="idler"),
              _pulley("a_b", (0.3, 0.3), 0.05, role="idler"), _pulley("c", (0.0, 0.3), 0.05, role="accessory", torque=0.1)]
    with pytest.raises(SceneError, match=r"^pulleys: the spans a -> b_c and a_b -> c would both be named a_b_c"):
        _scene(square)
    square[1]["name"] = "bc"
    assert "a_bc" in _scene(square).span_names()
    for name in ("tensioner_arm", "base_link"):
        two = _two_pulleys()
        two[1]["name"] = name
        with pytest.raises(SceneError, match=f"^pulleys.{name}.name: '{name}' names the tensioner arm's own joint"):
            _scene(two)


def test_at_most_64_pulleys():
    ring = [_pulley(f"p{k}", (math.cos(2 * math.pi * k / 65), math.sin(2 * math.pi * k / 65)), 0.01,
                    role="driver" if k == 0 else "idler", **({"torque": 0.1} if k == 0 else {})) for k in range(65)]
    with pytest.raises(SceneError, match=r"^pulleys: at most 64 pulleys .*got 65"):
        _scene(ring)


def test_the_onset_names_the_pulley_whose_use_crosses_first_at_the_crossing_time():
    """Two pulleys past the limit in the same sample: the one whose friction use crossed 1 first (interpolated
    between the samples), not the first in the list; its time the crossing's, not the sample's."""
    from belt_drive_ros.core.network.model import NetworkRun

    run = NetworkRun.__new__(NetworkRun)
    object.__setattr__(run, "time", np.array([0.0, 1.0, 2.0]))
    object.__setattr__(run, "friction_use", np.array([[0.1, 0.5], [0.5, 0.9], [1.3, 1.1]]))

    class Scene:
        pulleys = [type("P", (), {"name": "drv"})(), type("P", (), {"name": "acc"})()]

    # drv crosses at 1 + 0.5 / 0.8 = 1.625 s, acc at 1 + 0.1 / 0.2 = 1.5 s: acc first, though drv's use is larger
    name, t, use = run.capstan_onset(Scene)
    assert (name, use) == ("acc", 1.1) and t == pytest.approx(1.5, rel=1e-15)
    object.__setattr__(run, "friction_use", np.array([[1.2, 1.4], [1.5, 1.6], [2.0, 2.0]]))  # beyond from the start
    assert run.capstan_onset(Scene) == ("acc", 0.0, 1.4)


def test_the_hub_load_takes_the_centrifugal_tension_off_both_spans():
    """A belt of 0.1 kg/m at 30 m/s (w = 90 N) presses on a pulley with T - w: the hub load of a two-pulley drive
    is |(T_1 - w) e_1 - (T_0 - w) e_0|, by hand, not |T_1 e_1 - T_0 e_0| (the same as without mass, before)."""
    two = [_pulley("a", (0.0, 0.0), 0.1, role="driver", torque=5.0), _pulley("b", (0.4, 0.0), 0.05, role="accessory", torque=5.0)]
    data = {"kind": "network", "pulleys": two, "duration": 0.02, "dt": 1e-4, "initial_speed": 300.0,
            "belt": {"EA": 1.0e5, "damping": 0.0, "mass_per_length": 0.1, "installed_tension": 300.0}}
    scene = NetworkScene.from_mapping(data)
    run = simulate(scene, model="flexible")
    e = np.asarray(scene.geometry.directions, dtype=float)
    v = run.speed[:, 0] * 0.1
    w = 0.1 * v * v
    T = run.tension
    for i, prev in ((0, 1), (1, 0)):
        by_hand = np.hypot((T[:, i] - w) * e[i, 0] - (T[:, prev] - w) * e[prev, 0],
                           (T[:, i] - w) * e[i, 1] - (T[:, prev] - w) * e[prev, 1])
        np.testing.assert_allclose(run.hub_load[:, i], by_hand, rtol=1e-12)
    massless = np.hypot(T[:, 0] * e[0, 0] - T[:, 1] * e[1, 0], T[:, 0] * e[0, 1] - T[:, 1] * e[1, 1])
    assert np.min(w) > 70.0 and np.all(massless - run.hub_load[:, 0] > 1.8 * w)  # nearly parallel spans: ~2 w less


def test_the_printed_spring_preload_given_back_gives_the_same_installed_tension():
    """`belt-drive scenes fead_i4` prints the spring preload; given back as tensioner.preload (instead of the
    installed tension) it rebuilds the same belt (before: printed negative, which the scene file refuses)."""
    import re as regex

    from belt_drive_ros.io.network_plot import describe

    text = describe(load_network("fead_i4"))
    preload = float(regex.search(r"spring preload (\S+) N m", text).group(1))
    assert preload > 0.0
    from importlib import resources

    from belt_drive_ros.io.inputs import parse_yaml

    data = parse_yaml((resources.files("belt_drive_ros") / "scenes" / "networks" / "fead_i4.yaml").read_text(), "fead_i4")
    T0 = data["belt"].pop("installed_tension")
    data["tensioner"]["preload"] = preload
    again = NetworkScene.from_mapping(data)
    assert again.belt.installed_tension == pytest.approx(T0, rel=1e-3)  # (the printed preload has 4 digits)


def test_modes_say_when_the_operating_point_has_a_slack_span_or_a_slipping_pulley(tmp_path, capsys):
    """A load torque the belt cannot hold at its installed tension: the static tensions leave a pulley past its capstan
    limit, so the linearised modes do not describe the drive; `modes` says so on stderr (before: nothing)."""
    import yaml

    from belt_drive_ros.cli import main
    from belt_drive_ros.core.network.model import operating_limits

    two = [_pulley("drv", (0.0, 0.0), 0.1, role="driver", torque=40.0), _pulley("acc", (0.4, 0.0), 0.05, role="accessory",
                                                                                    torque=60.0)]
    scene = _scene(two)
    problems = operating_limits(NetworkModel.build(scene), 50.0)
    assert problems and any("pulley acc beyond its capstan limit" in p or "slack" in p for p in problems)
    path = tmp_path / "over.yaml"
    path.write_text(yaml.safe_dump({"kind": "network", "pulleys": two, "duration": 0.1, "dt": 1e-4, "initial_speed": 50.0,
                                    "belt": {"EA": 1.0e5, "damping": 0.0, "mass_per_length": 0.0,
                                             "installed_tension": 300.0}}))  # fmt: skip
    assert main(["modes", str(path)]) == 0
    err = capsys.readouterr().err
    assert err.startswith("warning: at this operating point ") and "assume a belt that neither slackens nor slips" in err
    assert operating_limits(NetworkModel.build(load_network("fead_i4")), load_network("fead_i4").operating_speed) == []


def test_an_idle_run_is_not_called_inaccurate_for_its_rounding_noise():
    """Zero torques from rest: the tensions move by rounding only; the guard's scale has a floor of a millionth of the
    installed tension, so that noise is no 'INACCURATE' verdict (before: 3.5e-9 N read 1 % of a 3e-7 N 'peak change')."""
    ring = [_pulley(f"p{j}", (0.3 * math.cos(2 * math.pi * j / 12), 0.3 * math.sin(2 * math.pi * j / 12)), 0.03,
                    role="driver" if j == 0 else "accessory" if j == 1 else "idler", **({"torque": 0.0} if j < 2 else {}))
            for j in range(12)]  # fmt: skip
    run = simulate(_scene(ring, initial_speed=100.0), model="flexible", method="etd2")
    assert 0.0 < float(np.max(np.abs(run.tension - 300.0))) < 1e-6  # turning steadily: rounding alone moves them
    assert run.accuracy.startswith("accurate"), run.accuracy
    coarse = simulate(load_network("fead_i4"), duration=0.3, dt=4e-3, method="etd2", model="flexible")
    assert coarse.accuracy.startswith("INACCURATE")  # a real error still is one
