"""Torque sources and loads: values, vectorization, periodicity, round trips, errors naming the key."""

from __future__ import annotations

import math

import numpy as np
import pytest

from belt_drive_ros.core.errors import SceneError
from belt_drive_ros.core.sources import (
    Compressor,
    Constant,
    Engine,
    MotorCurve,
    Polynomial,
    Ramp,
    Schedule,
    Sine,
    Step,
    Table,
    make_profile,
)

SPECS = [
    {"type": "constant", "value": 2.5},
    {"type": "step", "initial": 1.0, "final": 3.0, "time": 0.2},
    {"type": "ramp", "start_value": 0.0, "end_value": 4.0, "start_time": 0.1, "end_time": 0.5},
    {"type": "sine", "mean": 1.0, "amplitude": 2.0, "frequency": 3.0, "phase": 0.4},
    {"type": "table", "times": [0.0, 0.2, 0.5], "values": [0.0, 2.0, 1.0], "interpolation": "linear"},
    {"type": "table", "times": [0.0, 0.2, 0.5], "values": [0.0, 2.0, 1.0], "interpolation": "previous"},
    {"type": "engine", "mean_torque": 20.0, "cylinders": 6, "strokes": 4, "harmonics": [15.0, 5.0],
     "speed_setpoint": 80.0, "governor_gain": 2.0, "max_torque": 200.0, "ramp_time": 0.3},
    {"type": "motor", "stall_torque": 60.0, "no_load_speed": 300.0, "soft_start_time": 0.5},
    {"type": "motor", "curve": [[0.0, 60.0], [150.0, 60.0], [314.0, 28.0]]},
    {"type": "polynomial", "c0": 0.5, "c1": 0.02, "c2": 2e-4},
    {"type": "compressor", "mean_torque": 18.0, "c1": 0.01, "cylinders": 2, "harmonics": [14.0, 4.0], "ramp_time": 0.1},
    {"type": "schedule", "periods": [[0.1, 0.3]], "active": {"type": "constant", "value": 5.0},
     "inactive": {"type": "polynomial", "c1": 0.1}},
]
IDS = [f"{s['type']}-{j}" for j, s in enumerate(SPECS)]


def test_every_kind_is_covered():
    from belt_drive_ros.core import sources

    assert {s["type"] for s in SPECS} == set(sources._REGISTRY)


@pytest.mark.parametrize("spec", SPECS, ids=IDS)
def test_round_trip_to_dict(spec):
    profile = make_profile(spec)
    again = make_profile(profile.to_dict())
    assert again == profile
    t = np.linspace(0.0, 1.0, 11)
    a = np.linspace(0.0, 20.0, 11)
    w = np.linspace(10.0, 200.0, 11)
    np.testing.assert_array_equal(again.torque(t, a, w), profile.torque(t, a, w))


@pytest.mark.parametrize("spec", SPECS, ids=IDS)
def test_scalar_and_array_evaluation_agree(spec):
    """Vectorized (open-loop fast path) and scalar (step loop) evaluations are the same numbers."""
    profile = make_profile(spec)
    t = np.linspace(0.0, 1.0, 23)
    a = np.linspace(-3.0, 40.0, 23)
    w = np.linspace(0.0, 250.0, 23)
    vec = np.broadcast_to(profile.torque(t, a, w), t.shape)
    scalar = np.array([profile.torque(float(ti), float(ai), float(wi)) for ti, ai, wi in zip(t, a, w)])
    assert all(isinstance(profile.torque(float(ti), float(ai), float(wi)), float) for ti, ai, wi in zip(t, a, w))
    np.testing.assert_allclose(vec, scalar, rtol=1e-15, atol=1e-15)
    assert np.all(np.isfinite(vec))


def test_number_is_constant():
    assert make_profile(3.0) == Constant(3.0)
    assert make_profile(2).torque(0.0) == 2.0


def test_open_loop_profile_values():
    assert Step(1.0, 3.0, 0.2).torque(0.1999) == 1.0 and Step(1.0, 3.0, 0.2).torque(0.2) == 3.0
    ramp = Ramp(0.0, 4.0, 0.1, 0.5)
    np.testing.assert_allclose(ramp.torque(np.array([0.0, 0.1, 0.3, 0.5, 1.0])), [0.0, 0.0, 2.0, 4.0, 4.0])
    sine = Sine(1.0, 2.0, 3.0, 0.4)
    assert sine.torque(0.25) == pytest.approx(1.0 + 2.0 * math.sin(2 * math.pi * 0.75 + 0.4), rel=1e-15)
    lin = Table((0.0, 0.2, 0.5), (0.0, 2.0, 1.0), "linear")
    hold = Table((0.0, 0.2, 0.5), (0.0, 2.0, 1.0), "previous")
    assert lin.torque(0.1) == pytest.approx(1.0) and hold.torque(0.1) == 0.0
    assert hold.torque(0.2) == 2.0 and hold.torque(0.49) == 2.0 and hold.torque(9.0) == 1.0
    assert lin.torque(-1.0) == 0.0 and lin.torque(9.0) == 1.0  # held outside


def test_engine_firing_pulses_by_crank_angle():
    engine = Engine(mean_torque=20.0, cylinders=6, strokes=4, harmonics=(15.0, 5.0))
    assert engine.pulses_per_revolution == 3.0  # 4-stroke: cylinders / 2
    assert Engine(cylinders=2, strokes=2).pulses_per_revolution == 2.0
    theta = np.linspace(0.0, 2 * math.pi, 50)
    period = 2 * math.pi / 3
    np.testing.assert_allclose(engine.torque(0.0, theta + period, 0.0), engine.torque(0.0, theta, 0.0), atol=1e-12)
    # The mean over one firing period is the mean torque.
    grid = np.linspace(0.0, period, 1000, endpoint=False)
    assert np.mean(engine.torque(0.0, grid, 0.0)) == pytest.approx(20.0, rel=1e-12)
    # 6 cylinders at 600 rpm: 30 Hz firing frequency (model.md).
    freqs = engine.excitation_frequencies(600 * 2 * math.pi / 60)
    assert freqs[0][0] == pytest.approx(30.0, rel=1e-12) and freqs[1][0] == pytest.approx(60.0, rel=1e-12)
    # crank_ratio: the crank turns crank_ratio times per wheel-M turn.
    geared = Engine(harmonics=(15.0,), crank_ratio=2.0)
    assert geared.excitation_frequencies(2 * math.pi)[0][0] == pytest.approx(6.0)


def test_engine_governor_and_ramp():
    engine = Engine(mean_torque=20.0, harmonics=(), speed_setpoint=80.0, governor_gain=2.0, max_torque=50.0, ramp_time=0.5)
    assert engine.state_dependent
    assert engine.torque(1.0, 0.0, 75.0) == pytest.approx(30.0)
    assert engine.torque(1.0, 0.0, 0.0) == pytest.approx(50.0)  # clipped at max_torque
    assert engine.torque(1.0, 0.0, 200.0) == 0.0  # never negative
    assert engine.torque(0.25, 0.0, 75.0) == pytest.approx(15.0)  # half way up the ramp


def test_motor_curves():
    line = MotorCurve(stall_torque=60.0, no_load_speed=300.0)
    assert line.torque(0.0, 0.0, 0.0) == 60.0 and line.torque(0.0, 0.0, 150.0) == pytest.approx(30.0)
    assert line.torque(0.0, 0.0, 300.0) == pytest.approx(0.0, abs=1e-12)
    soft = MotorCurve(stall_torque=60.0, no_load_speed=300.0, soft_start_time=0.5)
    assert soft.torque(0.25, 0.0, 0.0) == pytest.approx(30.0)
    curve = MotorCurve(curve=((0.0, 60.0), (150.0, 60.0), (314.0, 28.0)))
    assert curve.torque(0.0, 0.0, 100.0) == 60.0
    assert curve.torque(0.0, 0.0, 232.0) == pytest.approx(44.0)
    assert curve.torque(0.0, 0.0, 1000.0) == 28.0  # held beyond the end


def test_polynomial_and_compressor():
    poly = Polynomial(c0=0.5, c1=0.02, c2=2e-4)
    assert poly.torque(0.0, 0.0, 100.0) == pytest.approx(0.5 + 2.0 + 2.0)
    assert poly.torque(0.0, 0.0, -100.0) == pytest.approx(0.5 - 2.0 - 2.0)  # c2 s|s| opposes reverse motion
    comp = Compressor(mean_torque=18.0, cylinders=2, harmonics=(14.0, 4.0))
    a = np.linspace(0.0, 2 * math.pi, 40)
    np.testing.assert_allclose(comp.torque(0.0, a + math.pi, 0.0), comp.torque(0.0, a, 0.0), atol=1e-12)
    assert comp.excitation_frequencies(2 * math.pi)[0][0] == pytest.approx(2.0)


def test_schedule_switches():
    sched = make_profile(SPECS[-1])
    assert isinstance(sched, Schedule) and sched.state_dependent
    assert sched.torque(0.05, 0.0, 10.0) == pytest.approx(1.0)
    assert sched.torque(0.1, 0.0, 10.0) == 5.0 and sched.torque(0.2999, 0.0, 10.0) == 5.0
    assert sched.torque(0.3, 0.0, 10.0) == pytest.approx(1.0)
    labels = [label for _, label in sched.excitation_frequencies(10.0)]
    assert any("switching" in lab for lab in labels)


def test_state_dependence_flags():
    assert not any(make_profile(s).state_dependent for s in SPECS[:6])
    assert all(make_profile(s).state_dependent for s in SPECS[6:])


# ------------------------------------------------------------ errors
@pytest.mark.parametrize(
    "spec, fragment",
    [
        ({"type": "turbine"}, "drive.type"),
        ({"value": 1.0}, "drive.type"),
        ({"type": "constant", "valeu": 1.0}, "drive.valeu"),
        ({"type": "constant", "value": math.nan}, "constant.value"),
        ({"type": "sine", "frequency": math.inf}, "sine.frequency"),
        ({"type": "ramp", "start_time": 1.0, "end_time": 1.0}, "ramp.end_time"),
        ({"type": "table", "times": [0.0, 0.0], "values": [1.0, 2.0]}, "table.times"),
        ({"type": "table", "times": [0.0, 1.0], "values": [1.0]}, "table"),
        ({"type": "table", "times": [0.0, 1.0], "values": [1.0, 2.0], "interpolation": "cubic"}, "table.interpolation"),
        ({"type": "engine", "strokes": 3}, "engine.strokes"),
        ({"type": "engine", "cylinders": 0}, "engine.cylinders"),
        ({"type": "engine", "cylinders": 2.5}, "engine.cylinders"),
        ({"type": "engine", "crank_ratio": -1.0}, "engine.crank_ratio"),
        ({"type": "engine", "harmonics": [1.0, math.nan]}, "engine.harmonics"),
        ({"type": "motor", "no_load_speed": 0.0}, "motor.no_load_speed"),
        ({"type": "motor", "curve": [[0.0, 1.0]]}, "motor.curve"),
        ({"type": "motor", "curve": [[1.0, 1.0], [0.0, 2.0]]}, "motor.curve"),
        ({"type": "compressor", "cylinders": -2}, "compressor.cylinders"),
        ({"type": "schedule", "periods": [[0.5, 0.2]]}, "schedule.periods"),
        ({"type": "schedule", "active": {"type": "nope"}}, "schedule.active.type"),
    ],
)
def test_profile_errors_name_the_key(spec, fragment):
    with pytest.raises(SceneError) as info:
        make_profile(spec, "drive")
    message = str(info.value)
    assert message.startswith("drive")
    assert fragment in message


def test_profile_not_a_mapping():
    with pytest.raises(SceneError, match="load: expected a mapping"):
        make_profile("fast", "load")
    with pytest.raises(SceneError):
        make_profile(True, "load")


# ------------------------------------------------- one formula, three forms
def test_tables_interpolate_and_hold_as_numpy_does():
    """The kernel's table lookups against numpy's interp and searchsorted (sample points included exactly)."""
    rng = np.random.default_rng(5)
    xp = np.sort(rng.uniform(-1.0, 1.0, 9))
    fp = rng.normal(size=9)
    xs = np.concatenate([rng.uniform(-1.5, 1.5, 200), xp])
    linear, held = Table(xp, fp, "linear"), Table(xp, fp, "previous")
    np.testing.assert_allclose(linear.torque(xs), np.interp(xs, xp, fp), rtol=1e-15, atol=0)
    index = np.clip(np.searchsorted(xp, xs, side="right") - 1, 0, len(fp) - 1)
    assert np.array_equal(held.torque(xs), fp[index])
    assert [held.torque(float(x)) for x in xs] == fp[index].tolist()


@pytest.mark.parametrize("spec", SPECS, ids=IDS)
def test_flags_match_what_the_torque_reads(spec):
    """state_dependent / uses_angle, stated per profile, match what the torque does."""
    profile = make_profile(spec)
    f = profile.scalar_torque()
    rng = np.random.default_rng(6)
    points = rng.uniform((0.0, -20.0, 0.0), (1.0, 20.0, 300.0), size=(50, 3))
    moves_angle = any(f(t, a, w) != f(t, a + 0.7, w) for t, a, w in points)
    moves_speed = any(f(t, a, w) != f(t, a, w + 13.0) for t, a, w in points)
    assert profile.uses_angle == moves_angle
    assert profile.state_dependent == (moves_angle or moves_speed)


def test_engine_without_pulses_or_governor_is_open_loop():
    """Derived flags are exact: a pulse-free, ungoverned engine reads neither angle nor speed."""
    engine = Engine(harmonics=(), speed_setpoint=None, ramp_time=0.2)
    assert not engine.state_dependent and not engine.uses_angle
    assert engine.torque(0.1, 5.0, 50.0) == pytest.approx(10.0)


def test_every_kind_has_a_data_form_and_a_kernel_branch():
    """Each registered profile encodes to kernel data; an unknown kind code evaluates to NaN, never to a number."""
    from belt_drive_ros.core import kernel_profiles, profile_data as D

    for spec in SPECS:
        assert make_profile(spec).data() is not None
    row = np.zeros((1, D.WIDTH))
    assert math.isnan(kernel_profiles.profile_torque(np.array([99]), row, np.zeros(1), np.zeros(1), 0.0, 0.0, 0.0))



def test_table_search_finds_the_index_bisection_finds():
    """The kernel's table search (started where an evenly spaced table would hold ``x``, widened by
    doubling) returns bisect_right's index: even, jittered, clustered and tiny tables, times at, between,
    before and after the points, NaN included; and a table's hold reads the value numpy's searchsorted gives."""
    import bisect

    from belt_drive_ros.core.kernel_profiles import _bisect_right

    rng = np.random.default_rng(7)
    tables = [np.arange(2000) * 1e-3, np.arange(2000) * 1e-3 + rng.uniform(-4e-4, 4e-4, 2000),
              np.sort(np.concatenate([rng.uniform(0, 1, 300), rng.uniform(5, 5.001, 300)])),
              np.cumsum(rng.exponential(1.0, 500)), np.array([0.0, 1.0, 2.0]), np.arange(9.0)]
    for xs in tables:
        xs = np.unique(xs)
        padded = np.concatenate([np.full(3, -1e300), xs, np.full(2, 1e300)])
        queries = np.concatenate([xs, rng.uniform(xs[0] - 1, xs[-1] + 1, 400), np.nextafter(xs, np.inf)[::7],
                                  np.nextafter(xs, -np.inf)[::7], [math.inf, -math.inf]])
        for x in queries.tolist():
            assert _bisect_right(padded, 3, xs.size, x) == bisect.bisect_right(xs.tolist(), x), (xs.size, x)
        assert _bisect_right(padded, 3, xs.size, math.nan) == _bisect_right(padded, 3, xs.size, math.nan)  # no hang
    held = Table(times=tuple(tables[1][:50].tolist()), values=tuple(range(50)), interpolation="previous")
    t = rng.uniform(0.0, 0.06, 300)
    expected = np.arange(50.0)[np.clip(np.searchsorted(tables[1][:50], t, side="right") - 1, 0, 49)]
    np.testing.assert_array_equal(held.torque(t), expected)


@pytest.mark.parametrize("harmonics", [(15.0,), (15.0, 5.0), (15.0, 0.0, 5.0), (0.0, 7.0), (15.0, 5.0, 2.0, 0.0, 1.0)])
def test_harmonic_series_values(harmonics):
    """Engine and compressor torques are the series ``sum_k A_k sin(k arg)`` (each term by its own sine here) to
    rounding, at crank angles up to ~3000 rad: one to three harmonics run from scalars, five from the profile's
    table; zero amplitudes between and before nonzero ones keep the orders of those after them."""
    angle = np.linspace(-50.0, 1000.0, 2001)
    engine = Engine(mean_torque=20.0, cylinders=6, strokes=4, harmonics=harmonics, phase=0.3, crank_ratio=1.5)
    comp = Compressor(mean_torque=18.0, c1=0.01, cylinders=2, harmonics=harmonics, phase=-0.2)
    e_arg = engine.pulses_per_revolution * (1.5 * angle) + 0.3
    c_arg = 2.0 * angle - 0.2
    e_ref = 20.0 + sum(a * np.sin((k + 1) * e_arg) for k, a in enumerate(harmonics))
    c_ref = 18.0 + 0.01 * 40.0 + sum(a * np.sin((k + 1) * c_arg) for k, a in enumerate(harmonics))
    # (k arg is rounded at ~1e-13 rad for these angles: the terms agree to that, not to the last bit)
    np.testing.assert_allclose(engine.torque(0.0, angle, 0.0), e_ref, rtol=0.0, atol=1e-10)
    np.testing.assert_allclose(comp.torque(0.0, angle, 40.0), c_ref, rtol=0.0, atol=1e-10)
    # the compiled scalar call gives the array call's floats
    assert engine.torque(0.0, float(angle[777]), 0.0) == engine.torque(0.0, angle, 0.0)[777]


@pytest.mark.parametrize("kind", ["engine", "compressor"])
@pytest.mark.parametrize("value, message", [
    (300, r"\.harmonics: expected a list of amplitudes \[N m\], got int 300"),
    ({"a": 1}, r"\.harmonics: expected a list of amplitudes \[N m\], got dict"),
    ("300", r"\.harmonics: must be a number \(or numbers\), got '300'"),
    ([[1.0, 2.0]], r"\.harmonics\[0\]: must be a number, got tuple \(1.0, 2.0\)"),
    ([1.0, "x"], r"\.harmonics: must be a number \(or numbers\), got \[1.0, 'x'\]"),
    ([1.0, True], r"\.harmonics\[1\]: must be a number, got bool"),
    ([1.0, math.inf], r"\.harmonics: harmonic amplitudes must be finite"),
])  # fmt: skip
def test_harmonics_of_the_wrong_shape_are_named_in_one_line(kind, value, message):
    """Not a list of numbers: the message names the key (and the entry), not Python's own words ("'int' object is
    not iterable", "float() argument must be ... not 'tuple'")."""
    with pytest.raises(SceneError, match=message):
        make_profile({"type": kind, "harmonics": value})
    assert make_profile({"type": kind, "harmonics": np.array([3.0, 1.0])}).harmonics == (3.0, 1.0)
