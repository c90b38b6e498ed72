"""Issue 20's "nothing else advances time" and "the node tick computes without the GIL", checked by running.

* **No stepping loop in Python.** A fixed-step run's Python work must not grow with its number of steps: the
  steps are the compiled loops' (``kernel.linear_steps``/``wheel_steps``, ``kernel_hybrid.hybrid_steps``, the
  network loops). Each case runs at two durations with the same step, and the Python function calls of each
  run are counted (its second call; ``sys.setprofile``: every Python-level call, whatever module makes it); the count may
  grow by a few calls per output window or event, never by one or more per step. A loop over steps in Python
  (``integrator.step``, ``stage_scheme.step``, one kernel call per step) costs 1-160 calls per step: scipy's
  adaptive methods, which the issue keeps as references stepped in Python, are the detector's positive control.
* **The network node's tick** (``core/network/tick.py: network_tick``) lets another Python thread run while it
  computes, as ``test_audit_kernel`` shows for the paper node's linear and slipping ticks.

Two paths stepped in Python until this audit found them; both are in now, each checked below. The slipping
model's slip phases with ``trapezoidal`` (an implicit method with the slip force an extra input): the compiled
loop solves the implicit stage with the extra input (~164 Python calls per step on bsg_start before, 0.003 after;
``tests/test_kernel_implicit.py`` shows the floats are the ones the Python steps gave). A torque recorded at the
step rate with a load that reads time (``bags/compressor_cycling``: every step clamped at its
own breakpoints) was one clamped kernel call per step planned in Python (~18 calls per step); its clamps are
planned by numpy and stepped in one compiled call (``kernel.clamped_steps``).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from belt_drive_ros.core.simulate import simulate
from belt_drive_ros.io.scenes import load_network, load_scene

ROOT = Path(__file__).resolve().parents[1]
#: Python calls per extra step above which a path steps in Python (the compiled paths: 0 to 0.13, from output
#: windows and located events; a Python step loop: 1 or more)
PER_STEP = 0.5


def _python_calls(run) -> int:
    """Python function calls made by ``run()`` (after one call that fills what it builds once)."""
    run()
    calls = [0]

    def profile(frame, event, arg):
        if event == "call":
            calls[0] += 1

    sys.setprofile(profile)
    try:
        run()
    finally:
        sys.setprofile(None)
    return calls[0]


def _per_extra_step(run, short: float, long: float, dt: float) -> float:
    """Python calls per step that ``run(duration)`` makes beyond ``run(short)`` for ``run(long)``."""
    return (_python_calls(lambda: run(long)) - _python_calls(lambda: run(short))) / round((long - short) / dt)


SCENES = ("paper", "e_motor_start", "truck_compressor", "bsg_start")
LINEAR_METHODS = ("exact", "etd2", "etd4", "lawson5", "rk4", "trapezoidal")
#: the slipping model (symplectic_euler is refused); trapezoidal: an implicit stage with the slip force as an input
SLIP_METHODS = ("exact", "etd2", "etd4", "lawson5", "rk4", "trapezoidal")
DT = 1e-4


@pytest.mark.parametrize("model, methods", [("rigid", LINEAR_METHODS), ("flexible", LINEAR_METHODS),
                                            ("slipping", SLIP_METHODS)])
@pytest.mark.parametrize("name", SCENES)
def test_simulate_steps_no_step_in_python(name, model, methods):
    """Every shipped scene, each model and fixed-step method (bsg_start's belt slips from 30 ms on: slip phases
    and events inside the run; its belt has a mass, so the slip force is an input of the drive speed)."""
    scene = load_scene(name)
    for method in methods:
        growth = _per_extra_step(lambda d: simulate(scene, model=model, method=method, dt=DT, duration=d,
                                                    check_stability=False), 0.1, 0.2, DT)
        assert growth < PER_STEP, (name, model, method, growth)


def test_the_detector_sees_a_run_stepped_in_python():
    """scipy's RK45 (a reference the issue keeps, stepped in Python): well above the bound."""
    scene = load_scene("paper")
    growth = _per_extra_step(lambda d: simulate(scene, model="flexible", method="RK45", dt=1e-3, duration=d,
                                                check_stability=False), 0.2, 0.4, 1e-3)
    assert growth > 2 * PER_STEP


@pytest.mark.parametrize("tier", ["rigid", "flexible", "slipping"])
@pytest.mark.parametrize("name", ["fead_i4", "paper_network", "bsg_start_network"])
def test_network_runs_step_no_step_in_python(name, tier):
    from belt_drive_ros.core.network.simulate import simulate as network_simulate

    scene = load_network(name)
    growth = _per_extra_step(lambda d: network_simulate(scene, duration=d, model=tier, check_accuracy=False),
                             0.2, 0.4, scene.dt)
    assert growth < PER_STEP, (name, tier, growth)


@pytest.mark.parametrize("name", ["paper", "truck_compressor", "bsg_start"])
def test_a_streamed_run_steps_no_step_in_python(name):
    from belt_drive_ros.core.stream import stream

    scene = load_scene(name)
    growth = _per_extra_step(lambda d: list(stream(scene, duration=d, dt=DT, check_stability=False,
                                                   window_steps=10**7)), 0.1, 0.2, DT)
    assert growth < PER_STEP, (name, growth)


@pytest.mark.parametrize("name", ["engine_idle", "engine_runup", "e_motor_start"])
def test_a_torque_bag_replay_steps_no_step_in_python(name):
    """The reference recordings' torque bags (a breakpoint on every step: every step clamped, one compiled call)."""
    from belt_drive_ros.io.torque_bag import scene_with_torque_bag

    scene = scene_with_torque_bag(load_scene(str(ROOT / "bags" / f"{name}.yaml")),
                                  ROOT / "bags" / f"{name}_torque.mcap")
    growth = _per_extra_step(lambda d: simulate(scene, duration=d, check_stability=False), 0.6, 1.2, scene.dt)
    assert growth < PER_STEP, (name, growth)


def _bag_scene(name: str, **overrides):
    from belt_drive_ros.io.torque_bag import scene_with_torque_bag

    scene = scene_with_torque_bag(load_scene(str(ROOT / "bags" / f"{name}.yaml")), ROOT / "bags" / f"{name}_torque.mcap")
    return scene.with_overrides(**overrides) if overrides else scene


@pytest.mark.parametrize("method", ["etd4", "exact", "rk4", "trapezoidal"])
@pytest.mark.parametrize("model", ["rigid", "flexible"])
def test_a_torque_bag_with_a_load_reading_time_steps_no_step_in_python(model, method):
    """``bags/compressor_cycling``: a breakpoint on every knot and a load that reads time (a schedule of compressors),
    so every step has its own clamps; run whole, with a progress callback (``belt-drive sim``'s
    bar) and streamed (``stream``). ~18 Python calls per step before the clamps went into the compiled loop."""
    from belt_drive_ros.core.stream import stream

    scene = _bag_scene("compressor_cycling")
    assert scene.load.kind == "schedule"
    growth = _per_extra_step(lambda d: simulate(scene, model=model, method=method, duration=d, check_stability=False),
                             0.6, 1.2, scene.dt)
    assert growth < PER_STEP, ("run", growth)
    growth = _per_extra_step(lambda d: simulate(scene, model=model, method=method, duration=d, check_stability=False,
                                                progress=lambda f: None), 0.6, 1.2, scene.dt)
    assert growth < PER_STEP, ("progress", growth)
    windows = scene.with_overrides(model=model, method=method)
    growth = _per_extra_step(lambda d: list(stream(windows.with_overrides(duration=d), check_stability=False,
                                                   window_steps=10**7)), 0.6, 1.2, scene.dt)
    assert growth < PER_STEP, ("stream", growth)


def test_a_torque_bag_advanced_off_the_grid_steps_no_step_in_python():
    """``Stepper.advance`` over the recording (the run's whole steps between partial first and last steps), the
    clamped steps in the compiled runs, not one call each."""
    from belt_drive_ros.core.model import make_model
    from belt_drive_ros.core.stepper import Plant, Stepper

    scene = _bag_scene("compressor_cycling")
    stepper = Stepper(Plant(make_model("flexible", scene.params), scene.drive, scene.load), "etd4", scene.dt)
    x0 = scene.initial_state.vector("flexible", scene.params.ratio)
    growth = _per_extra_step(lambda d: stepper.advance(x0, 0.00031, 0.00031 + d), 0.6, 1.2, scene.dt)
    assert growth < PER_STEP, growth


# ------------------------------------------------------------------ the network node's tick and the GIL
def test_the_network_node_tick_runs_without_the_gil():
    """A long compiled network tick (fead_i4, flexible tier: ``network_tick``) lets this thread's Python run."""
    from test_audit_kernel import _python_runs_during

    from belt_drive_ros.io.network_bag import NetworkLayout
    from belt_drive_ros.ros.network_stepper import NetworkStepper

    scene = load_network("fead_i4")
    stepper = NetworkStepper(scene, tier="flexible")
    layout = NetworkLayout(scene)
    stepper.use_joints(float(layout.arm[3]) if layout.arm else 0.0, layout.joint_encoder().layout)
    stepper.hold(scene.driver, 10.0)
    first, steps = 1000, 100_000  # past the crank's ramp (its breakpoint at 0.1 s): whole steps, one compiled call
    x = np.ascontiguousarray(stepper.initial())

    def tick():
        stepper.tick(x.copy(), first, first + steps)
        assert stepper.fresh == first + steps  # the compiled tick ran (advance() leaves fresh at -1)

    assert _python_runs_during(tick) > 1000
