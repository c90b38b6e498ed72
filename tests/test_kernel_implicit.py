"""An implicit method (``trapezoidal``) in the compiled loop (``kernel.wheel_steps``) is the reference step
(``stage_scheme.step``, which ``integrator.step`` runs) float for float: the same fixed point on every input of the
implicit stage (the torques and the slipping belt's speed-dependent slip force), the same sums
(``x+ = free + G u``). So the slipping belt's slip phases with a belt mass (the slip force an extra input) run in
the compiled loop with the floats they had when ``integrator.step`` stepped them in Python."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from belt_drive_ros.core import stepper as stepper_module
from belt_drive_ros.core.kernel_loop import FrictionForce
from belt_drive_ros.core.model import make_model
from belt_drive_ros.core.simulate import Simulator, simulate
from belt_drive_ros.core.stepper import Plant
from belt_drive_ros.io.scenes import load_scene


def _reference(integrator, inputs, times, x):
    """States at ``times[1:]`` by ``integrator.step`` (the Python reference), one step at a time."""
    out = np.empty((times.size - 1, x.size))
    for k in range(times.size - 1):
        x = integrator.step(float(times[k]), x, inputs)
        out[k] = x
    return out


@pytest.mark.parametrize("model", ["rigid", "flexible"])
@pytest.mark.parametrize("name", ["paper", "e_motor_start", "truck_compressor", "bsg_start"])
def test_the_compiled_trapezoidal_step_is_the_reference_step(name, model):
    """Every shipped scene's torques (state-dependent: governors, motor curves, compressors), 300 steps of 1 ms."""
    scene = load_scene(name)
    sim = Simulator(make_model(model, scene.params), scene.drive, scene.load, "trapezoidal", 1e-3, check_stability=False)
    plant, loop = sim.stepper.plant, sim.stepper.loop
    assert loop is not None
    x0 = np.ascontiguousarray(scene.initial_state.vector(model, scene.params.ratio), dtype=float)
    times = 1e-3 * np.arange(301, dtype=float)
    out = np.empty((300, x0.size))
    assert loop(times, x0.copy(), out)[:2] == (300, 0)
    want = _reference(sim.integrator, plant.inputs, times, x0.copy())
    assert np.all(np.isfinite(want)) and np.ptp(want[:, -1]) > 0.0
    assert out.tobytes() == want.tobytes(), np.max(np.abs(out - want))


def _mass_plant(scene, sigma: float = 1.0):
    """A slip phase's plant of ``scene`` with the slip force ``sigma Q_max(omega_M)`` as its extra input."""
    from belt_drive_ros.core.slip_run import SlippingSimulator

    sim = SlippingSimulator(scene.params, scene.drive, scene.load, "trapezoidal", 1e-4)
    return sim.phase_stepper(("mass", sigma))


def test_a_slip_phase_with_the_slip_force_steps_compiled_as_the_reference():
    """bsg_start's slip phase (a belt with mass: the slip force is an input of the drive speed), trapezoidal."""
    scene = load_scene("bsg_start")
    st = _mass_plant(scene)
    plant = st.plant
    assert plant.extra and isinstance(plant.extra[0], FrictionForce)
    loop = plant.kernel_loop(st.integrator)
    assert loop is not None  # before: None (an implicit method with an extra input stepped in Python)
    n = plant.model.A.shape[0]
    x0 = np.zeros(n)
    times = 1e-4 * np.arange(2001, dtype=float)
    out = np.empty((2000, n))
    assert loop(times, x0.copy(), out)[:2] == (2000, 0)
    want = _reference(st.integrator, plant.inputs, times, x0.copy())
    assert np.all(np.isfinite(want)) and np.ptp(want[:, -1]) > 0.0
    assert out.tobytes() == want.tobytes(), np.max(np.abs(out - want))


def _python_slip_phases(monkeypatch):
    """The old path: a plant with extra inputs and an implicit method has no compiled loop (``integrator.step``)."""
    compiled = Plant.kernel_loop

    def kernel_loop(self, integrator, guard=None):
        if self.extra and integrator.scheme.implicit:
            return None
        return compiled(self, integrator, guard)

    monkeypatch.setattr(stepper_module.Plant, "kernel_loop", kernel_loop)


@pytest.mark.parametrize("case", ["bsg_start", "truck_compressor with a belt mass"])
def test_slipping_trapezoidal_runs_give_the_floats_the_python_steps_gave(case, monkeypatch):
    """A whole slipping run (stick and slip phases, events located) with its slip phases compiled equals the run
    stepped through ``integrator.step``: states, events and slip directions, bit for bit."""
    scene = load_scene(case.split()[0])
    if "mass" in case:
        scene = scene.with_params(dataclasses.replace(scene.params, belt_mass=0.3))

    def run():  # parameters of their own: no stepper of the other run is shared (they are kept per parameter set)
        own = scene.with_params(dataclasses.replace(scene.params))
        return simulate(own, model="slipping", method="trapezoidal", dt=2e-4, duration=0.6, check_stability=False)

    compiled = run()
    with monkeypatch.context() as m:
        _python_slip_phases(m)
        python = run()
    assert len(python.events) >= 3  # the belt slips and sticks again inside the run
    assert compiled.states.tobytes() == python.states.tobytes()
    assert repr(compiled.events) == repr(python.events)
