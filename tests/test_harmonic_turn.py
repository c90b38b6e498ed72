"""The time loops' harmonics after a step's first stage: sine and cosine turned from that stage's angle
(``kernel_profiles._sincos_near``) instead of two library calls per stage, within a few ulp of the library's.

A step's first stage calls ``sin`` and ``cos`` and anchors there; a later stage whose argument lies within
``TURN`` of the anchor turns the anchor's pair by the difference (its sine and cosine by Taylor series). The
dispatcher (``torque``), a result's torques (``profile_torque_array``) and the first stage keep the library's
floats."""

from __future__ import annotations

import math

import numpy as np
import pytest

from belt_drive_ros.core import kernel_profiles as kp
from belt_drive_ros.core.model import make_model
from belt_drive_ros.core.simulate import Simulator
from belt_drive_ros.io.scenes import load_scene

ULP1 = 2.0**-52  # the spacing of floats at 1


@pytest.fixture
def interpreted(monkeypatch):
    """The helpers ``_harmonics`` and ``_harmonics_near`` call, as Python too: their ``py_func`` calls the module's
    globals, and a compiled helper called from Python compiles a specialisation of its own (three compilations no
    run needs, written to the disk cache by the suite)."""
    for name in ("_top", "_series", "_sincos_near"):
        monkeypatch.setattr(kp, name, getattr(kp, name).py_func)


def _turned(arg, a0):
    s0, c0 = math.sin(a0), math.cos(a0)
    return kp._sincos_near.py_func(arg, (a0, s0, c0))


@pytest.mark.parametrize("a0", [0.0, 1e-3, -2.5, 37.0, 2300.0, -1.0e4, 1.0e5])
def test_a_turned_pair_is_the_librarys_within_a_few_ulp(a0):
    """Across the whole turn (both signs, its ends included) at small and large anchors: |sin - sin_lib| and
    |cos - cos_lib| <= 3 ulp of 1, and the anchor is kept."""
    rng = np.random.default_rng(7)
    deltas = np.concatenate([rng.uniform(-kp.TURN, kp.TURN, 4000), [kp.TURN, -kp.TURN, 0.0, 1e-300, -1e-12]])
    worst = 0.0
    for d in deltas:
        arg = a0 + float(d)
        s, c, anchor = _turned(arg, a0)
        assert anchor == (a0, math.sin(a0), math.cos(a0))
        worst = max(worst, abs(s - math.sin(arg)), abs(c - math.cos(arg)))
    assert worst <= 3 * ULP1, worst / ULP1


def test_beyond_the_turn_or_without_an_anchor_the_library_is_called_and_anchors_there():
    for arg, anchor in ((1000.0 + kp.TURN * 1.01, (1000.0, math.sin(1000.0), math.cos(1000.0))), (3.0, kp.NO_ANCHOR)):
        s, c, new = kp._sincos_near.py_func(arg, anchor)
        assert (s, c) == (math.sin(arg), math.cos(arg)) and new == (arg, s, c)
    s, c, new = kp._sincos_near.py_func(math.nan, kp.NO_ANCHOR)  # a diverged angle stays NaN
    assert s != s and c != c


def test_harmonics_without_an_anchor_are_the_dispatchers_floats(interpreted):
    """:data:`NO_ANCHOR` (a step's first stage, a result's torques): the library's sin (one harmonic) or sin and cos
    (more), as ``torque``, and the argument becomes the anchor."""
    for amplitudes in ((300.0, 0.0, 0.0), (300.0, 90.0, 0.0), (0.0, 4.0, 1.0)):
        for arg in (0.3, 2300.7, -41.0):
            want = kp._harmonics.py_func(15.0, True, amplitudes, arg)
            got = kp._harmonics_near.py_func(15.0, True, amplitudes, arg, kp.NO_ANCHOR)
            assert got == (*want, (arg, math.sin(arg), math.cos(arg)))
    assert kp._harmonics_near.py_func(15.0, True, (0.0, 0.0, 0.0), 1.0, kp.NO_ANCHOR) == (15.0, True, kp.NO_ANCHOR)


@pytest.mark.parametrize("amplitudes", [(300.0, 90.0, 0.0), (14.0, 4.0, 2.0), (1.0, 0.0, 0.0)])
def test_turned_harmonics_are_the_series_within_rounding(amplitudes, interpreted):
    """The harmonic sum from a turned pair equals the dispatcher's within a few ulp of the amplitudes' sum."""
    a0 = 2300.0
    anchor = (a0, math.sin(a0), math.cos(a0))
    scale = sum(abs(a) for a in amplitudes) * ULP1
    for d in np.linspace(-kp.TURN, kp.TURN, 101):
        arg = a0 + float(d)
        got, _, kept = kp._harmonics_near.py_func(15.0, True, amplitudes, arg, anchor)
        want, _ = kp._harmonics.py_func(15.0, True, amplitudes, arg)
        assert kept == anchor
        assert abs(got - want) <= 8 * scale + 4 * abs(want) * ULP1


@pytest.mark.parametrize("name, method", [("truck_compressor", "etd4"), ("truck_compressor", "rk4"), ("bsg_start", "etd2")])
def test_the_loop_with_turned_harmonics_is_the_reference_step_to_rounding(name, method):
    """The compiled loop (later stages turned) against ``integrator.step`` (every torque by the library), 600 steps
    of the flexible model with the scene's engine / compressor harmonics: each coordinate within 1e-12 of its
    range; ``exact`` (one stage: nothing turned) to the bit."""
    scene = load_scene(name)
    x0 = np.ascontiguousarray(scene.initial_state.vector("flexible", scene.params.ratio), dtype=float)
    x0[2] = max(x0[2], 50.0)  # turning from the first step
    for m in (method, "exact"):
        sim = Simulator(make_model("flexible", scene.params), scene.drive, scene.load, m, scene.dt, check_stability=False)
        times = scene.dt * np.arange(601, dtype=float)
        out = np.empty((600, 4))
        assert sim.stepper.loop(times, x0.copy(), out)[:2] == (600, 0)
        x, want = x0.copy(), np.empty((600, 4))
        for k in range(600):
            x = sim.integrator.step(float(times[k]), x, sim.stepper.plant.inputs)
            want[k] = x
        if m == "exact":
            assert out.tobytes() == want.tobytes()
        else:
            scale = np.max(np.abs(want), axis=0)
            assert np.max(np.abs(out - want) / scale) < 1e-12
