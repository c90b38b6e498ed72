"""The slipping belt's compiled hybrid loop (core/kernel_hybrid.py) and event step (core/kernel_slip.py).

* the compiled loop (each phase in the linear loop, the event steps
  compiled) equals every grid step taken as a compiled event step, to
  rounding, events alike;
* an advance tick by tick (the node's) equals one advance over the run;
* the kernels compile once: running slipping scenes adds no specialisation;
* ``NUMBA_DISABLE_JIT=1`` gives the same floats (a scene that slips in its first 60 ms).
"""

from __future__ import annotations

import numpy as np
import pytest

from belt_drive_ros.core import kernel_hybrid, kernel_slip
from belt_drive_ros.io.scenes import load_scene
from belt_drive_ros.core.slip_run import SlippingSimulator


def _sim(scene, **kw):
    return SlippingSimulator(scene.params, scene.drive, scene.load, scene.method, scene.dt, scene.method_options, False, **kw)


@pytest.mark.parametrize("name, duration", [("truck_compressor", 0.8), ("bsg_start", 0.3)])
def test_compiled_hybrid_loop_equals_event_steps_taken_one_by_one(name, duration):
    """The phases in the linear loop (etd4/etd2 matrices), events redone by the compiled event step, equal the
    hybrid stepper taking every grid step as an event step on the modal flow (the same method's step of any
    length), to rounding; events alike. truck_compressor: massless slip (Q a constant sixth state); bsg_start:
    a belt with mass (Q = sigma Q_max(omega_M) an input)."""
    from belt_drive_ros.benchmarks.slip_reference import HybridStepper

    scene = load_scene(name)
    y0 = scene.initial_state.vector("slipping", scene.params.ratio)
    sim = _sim(scene, lazy=True)
    time, states, modes, sigmas = sim.run(duration, y0)
    assert sim._compiled() is not None
    hs = HybridStepper(sim.model, sim.plant.scalar_drive, sim.plant.scalar_load, scene.method,
                       data=(*sim.plant.data, sim.plant.uses_angle))  # fmt: skip
    ref = hs.run(time, y0, breakpoints=sim.breakpoints)
    assert sum(e.kind == "onset" for e in sim.events) >= 1
    assert [e.kind for e in ref.events] == [e.kind for e in sim.events]
    np.testing.assert_allclose([e.time for e in sim.events], [e.time for e in ref.events], rtol=0.0, atol=1e-12)
    np.testing.assert_array_equal(modes, ref.mode)
    np.testing.assert_array_equal(sigmas, ref.sigma)
    error = np.max(np.abs(states - ref.states) / np.max(np.abs(ref.states), axis=0), axis=0)
    assert np.all(error < 1e-10), error


def test_advance_tick_by_tick_equals_one_run():
    """The node's ticks (1 ms, two grid steps each) give the offline run's states and events bit for bit."""
    scene = load_scene("truck_compressor")
    y0 = scene.initial_state.vector("slipping", scene.params.ratio)
    whole = _sim(scene)
    time, states, modes, _ = whole.run(0.7, y0)
    ticks = _sim(scene)
    state, events = ticks.initial(y0), []
    for k in range(700):
        state = ticks.advance(state, k * 1e-3, (k + 1) * 1e-3, events=events)
        i = int(np.searchsorted(time, (k + 1) * 1e-3 - 1e-12))
        np.testing.assert_array_equal(ticks.state_y(state), states[i])
        assert state.mode == modes[i]
    assert len(events) >= 2 and [e.time for e in events] == [e.time for e in whole.events]


def test_sticking_after_slip_runs_on_the_flexible_loop_with_the_load_angle_shifted():
    """Sticking after slip (s constant) runs on the flexible model's 4-state loop, the load's angle shifted by
    -s / r_3 in the phases of its harmonics (truck_compressor: the compressor's strokes read the crank angle): no
    5-state stick stepper is built, and the run equals the phase-by-phase path that steps the stick mode's 5-state
    plant (SlippingSimulator._advance_steps), events alike, to rounding."""
    from belt_drive_ros.core.slip_run import _joined

    scene = load_scene("truck_compressor")
    y0 = scene.initial_state.vector("slipping", scene.params.ratio)
    sim = _sim(scene, lazy=True)
    time, states, modes, _ = sim.run(0.7, y0)
    assert sum(e.kind == "restick" for e in sim.events) >= 2 and states[-1, 4] != 0.0
    assert "stick" not in sim._steppers  # the old code: the 5-state stick loop ran every stick-after-slip phase
    steps = _sim(scene)
    state, events = steps.initial(y0), []
    pieces = [(np.array([0.0]), steps.state_y(state)[None, :], state.mode, state.sigma)]
    steps._advance_steps(state, 0.0, 0.7, pieces, events)
    t_ref, y_ref, m_ref, _ = _joined(pieces)
    assert [e.kind for e in events] == [e.kind for e in sim.events]
    np.testing.assert_allclose([e.time for e in sim.events], [e.time for e in events], rtol=0.0, atol=1e-12)
    np.testing.assert_array_equal(time, t_ref)
    np.testing.assert_array_equal(modes, m_ref)
    error = np.max(np.abs(states - y_ref) / np.max(np.abs(y_ref), axis=0), axis=0)
    assert np.all(error < 1e-10), error


@pytest.mark.parametrize("method", ["rk4", "lawson5"])
def test_methods_without_a_modal_flow_slip_in_the_compiled_loop(method):
    """rk4 and lawson5 (no modal flow of their own) run the compiled hybrid loop too: their phases in the linear
    loop with the method's matrices, each event step compiled with its partial steps as etd4 (the Python event
    loop that took them with the method's own integrators is gone; it stays as the reference in
    benchmarks/slip_reference.py). Against etd4 at 1 us: the same events, and no larger an error than that Python
    loop per state coordinate (lawson5: smaller, the event times ~1e-9 s instead of ~1e-7 s)."""
    from belt_drive_ros.benchmarks.slip_reference import HybridStepper

    scene = load_scene("truck_compressor").with_overrides(method=method, dt=1e-4)
    y0 = scene.initial_state.vector("slipping", scene.params.ratio)
    sim = _sim(scene)
    time, states, modes, _ = sim.run(0.7, y0)
    assert sim._compiled() is not None  # the old code: None (no compiled event step for these methods)
    fine = _sim(scene.with_overrides(method="etd4", dt=1e-6))
    t_fine, y_fine, _, _ = fine.run(0.7, y0)
    truth = y_fine[np.searchsorted(t_fine, time - 1e-12)]
    hs = HybridStepper(sim.model, sim.plant.scalar_drive, sim.plant.scalar_load, method,
                       data=(*sim.plant.data, sim.plant.uses_angle))  # fmt: skip
    python = hs.run(time, y0, breakpoints=sim.breakpoints)
    assert len(fine.events) >= 4 and [e.kind for e in sim.events] == [e.kind for e in fine.events]
    np.testing.assert_array_equal(modes, python.mode)
    scale = np.max(np.abs(truth), axis=0)
    error = np.max(np.abs(states - truth) / scale, axis=0)
    python_error = np.max(np.abs(python.states - truth) / scale, axis=0)
    # 1e-9: the 1 us run's own error and the angles' rounding (phi_M ~ 54 rad), below either method's error
    assert np.all(error <= 1.01 * python_error + 1e-9), (error, python_error)
    assert max(abs(a.time - b.time) for a, b in zip(sim.events, fine.events)) < 2e-9


def test_the_hybrid_kernels_compile_once_whatever_the_scene():
    def counts():
        kernels = ((kernel_slip, "event_step"), (kernel_hybrid, "hybrid_steps"), (kernel_slip, "locate_event"))
        return {name: len(getattr(module, name).signatures) for module, name in kernels}

    from belt_drive_ros.core.warm import warm

    warm()
    first = counts()
    assert first == {"event_step": 1, "hybrid_steps": 1, "locate_event": 1}
    for name, duration, method in (("truck_compressor", 0.7, None), ("bsg_start", 0.1, None), ("truck_compressor", 0.55, "rk4")):
        scene = load_scene(name)
        if method:  # phases in the linear loop with the method's matrices, event steps compiled (partial steps etd4)
            scene = scene.with_overrides(method=method, dt=1e-4)
        sim = _sim(scene)
        sim.run(duration, scene.initial_state.vector("slipping", scene.params.ratio))
        assert sim.events
    assert counts() == first


def test_the_hybrid_kernel_interpreted_gives_the_same_floats(tmp_path):
    import os
    import subprocess
    import sys

    code = (
        "import sys, numpy as np\n"
        "from belt_drive_ros.io.scenes import load_scene\n"
        "from belt_drive_ros.core.slip_run import SlippingSimulator\n"
        "s = load_scene('bsg_start')\n"
        "sim = SlippingSimulator(s.params, s.drive, s.load, s.method, s.dt, s.method_options, False)\n"
        "t, y, m, g = sim.run(0.06, s.initial_state.vector('slipping', s.params.ratio))\n"
        "assert sim._compiled() is not None and sim.events\n"
        "np.save(sys.argv[1], np.column_stack([t, y, m, g]))\n"
    )
    out = {}
    for jit in ("0", "1"):
        path = tmp_path / f"run_{jit}.npy"
        done = subprocess.run([sys.executable, "-c", code, str(path)], env=dict(os.environ, NUMBA_DISABLE_JIT=jit),
                              capture_output=True, text=True, timeout=900)  # fmt: skip
        assert done.returncode == 0, done.stderr
        out[jit] = np.load(path)
    assert out["0"].shape == out["1"].shape and np.any(out["0"][:, 6] == 1)
    assert np.array_equal(out["0"], out["1"])


def _flow_phis(xs):
    """(e^x, phi_1(x), ..., phi_4(x)) of each x as the warmed kernel computes them: the modal flow
    (:func:`~.kernel_slip._flow`, its one cached signature, called with a step of 1 s from mode 0 whose three
    carried eigenvalues are the x: ``x * 1.0`` is x) leaves them in its work array (``wc[6:21]``, 3 x 5)."""
    f8, i8 = np.float64, np.int64
    z = np.zeros((2, 3, 12), dtype=np.complex128)
    r = np.zeros((2, 11))
    r[0, 10] = 3.0
    c = np.zeros(len(kernel_slip.CONSTS))
    c[16] = kernel_slip.EXACT
    kinds, row, one = np.zeros(1, dtype=i8), np.zeros((1, 1)), np.zeros(1)
    wf, wc = np.zeros(kernel_slip.FLOW_WORK), np.zeros(kernel_slip.FLOW_WORK, dtype=np.complex128)
    out = []
    for k in range(0, len(xs), 3):
        z[0, :, 0] = 0.0
        z[0, :len(xs[k:k + 3]), 0] = xs[k:k + 3]
        kernel_slip._flow(kernel_slip.STICK, 0.0, 0.0, np.zeros(5), 1.0, f8(np.inf), np.zeros(3), z, r, c,
                          np.zeros(2, dtype=i8), *[kernel_slip.DISPATCHED] * 2, kinds, row, one, one, kinds, row, one, one,
                          np.zeros(5), wf, wc)
        out.extend(tuple(v) for v in wc[6:21].reshape((3, 5)))
    return out[:len(xs)]


#: the helpers :func:`~.kernel_slip._phis4` calls (inline-only: compiled within the modal flow, never on their own)
PHI_HELPERS = ("_phi_series", "_phi_closed")


def _interpreted_phis4(xs):
    """:func:`~.kernel_slip._phis4` of each x as Python all the way (as under ``NUMBA_DISABLE_JIT=1``): its helpers
    swapped for their Python functions during the calls. ``_phis4.py_func`` alone called the compiled helpers from
    Python, which compiled and cached a (complex128,) and a (float64,) specialisation of each that ``make install``
    never warms (12-14 s of the suite's time in a fresh clone); asserts none gained a signature."""
    before = {name: len(getattr(kernel_slip, name).signatures) for name in PHI_HELPERS}
    with pytest.MonkeyPatch.context() as mp:
        for name in PHI_HELPERS:
            mp.setattr(kernel_slip, name, getattr(kernel_slip, name).py_func)
        out = [kernel_slip._phis4.py_func(np.complex128(x)) for x in xs]
    assert {name: len(getattr(kernel_slip, name).signatures) for name in PHI_HELPERS} == before
    return out


def test_the_modal_phi_functions_compiled_and_interpreted_give_the_same_floats():
    """e^x and phi_1..phi_4 of the modal flow, compiled and as Python, on 4,000 complex arguments either side
    of the series' radius: the same floats. numba's complex division and numpy's differ in the last bit
    for ~40 % of arguments, which made a 3 s truck_compressor run drift by 4e-12 after 0.56 s under
    NUMBA_DISABLE_JIT=1 (events 2e-16 s apart from the 36th on); 1/x is now formed by real arithmetic.
    The compiled floats are the warmed modal flow's (``_phis4`` inlined in it, as every run has it): no
    specialisation of its own compiled here (before, ``_phis4`` called from Python compiled and cached one,
    which ``make install`` never warms)."""
    rng = np.random.default_rng(7)
    radius = np.concatenate([rng.uniform(0.0, 0.5, 1000), rng.uniform(0.5, 60.0, 3000)])
    angle = rng.uniform(-np.pi, np.pi, radius.size)
    xs = radius * np.exp(1j * angle)
    misses = sum(kernel_slip._flow.stats.cache_misses.values())
    compiled = _flow_phis(xs)
    assert sum(kernel_slip._flow.stats.cache_misses.values()) == misses and len(kernel_slip._flow.signatures) == 1
    assert not kernel_slip._phis4.signatures  # (not compiled on its own)
    for x, got, want in zip(xs, compiled, _interpreted_phis4(xs)):  # (the kernel's complex numbers are numpy's)
        assert got == want, x


def test_the_phi_functions_of_a_real_argument_are_the_complex_paths_floats():
    """A real argument (every slip-mode eigenvalue times a step, one of the stick mode's) takes a real-arithmetic path
    in the compiled kernel: its e^x and phi_1..phi_4 are the complex formulas' floats bit for bit (the series below
    |x| = 0.5, the closed forms above, evaluated on ``x + 0j`` as the kernel did before), with zero imaginary parts,
    on 6,000 arguments either side of the radius (from 1e-12 to 1e3, both signs, and the radius itself)."""
    import cmath

    rng = np.random.default_rng(11)
    edges = [0.5, -0.5, np.nextafter(0.5, 0.0), np.nextafter(-0.5, -1.0), 1e-300, -7.5]
    xs = np.concatenate([rng.uniform(-0.5, 0.5, 2000), rng.uniform(-40.0, 8.0, 2000), -np.logspace(-12, 3, 1000),
                         np.logspace(-12, 0.9, 994), edges])
    compiled = _flow_phis(xs.astype(np.complex128))
    for x, got, interpreted in zip(xs, compiled, _interpreted_phis4(xs)):
        z = np.complex128(x)
        if abs(z) < 0.5:
            want = kernel_slip._phi_series.py_func(z)
        else:
            d = z.real * z.real + z.imag * z.imag
            r = np.complex128(complex(z.real / d, -z.imag / d))
            want = kernel_slip._phi_closed.py_func(np.complex128(cmath.exp(z)), r)
        assert all(g.imag == 0.0 for g in got), x
        assert [g.real for g in got] == [w.real for w in want], x
        assert got == interpreted, x  # (interpreted: the same real path)


def test_the_event_steps_work_arrays_carry_nothing_from_call_to_call():
    """The hybrid loop hands one pair of work arrays to all its event steps (``_event_step``: allocated once per run,
    not per call). Whatever they hold before a call (NaN here, never reset between calls), each event step gives the
    end state, mode, sigma and event rows of :func:`~.kernel_slip.event_step` with fresh zeroed arrays, bit for bit:
    exact, etd2 and etd4, onsets and resticks (the restick's stick check included), and steps without an event."""
    import math

    for method in ("exact", "etd2", "etd4"):
        scene = load_scene("truck_compressor").with_overrides(method=method)
        sim = _sim(scene, lazy=True)
        time, states, modes, sigmas = sim.run(0.8, scene.initial_state.vector("slipping", scene.params.ratio))
        arrays = sim.hybrid._kernel
        wf = np.full(kernel_slip.EVENT_WORK, np.nan)
        wc = np.full(kernel_slip.FLOW_WORK + kernel_slip.LOCATE_WORK, complex(np.nan, np.nan))
        switch = np.flatnonzero(np.diff(modes) != 0)
        steps = np.union1d(switch, switch + 3)  # each event step, and a step without an event after it
        kinds = set()
        for i in steps[steps < time.size - 1]:
            got = []
            for fresh in (True, False):
                y, y1, rows = states[i].copy(), np.empty(5), np.zeros((kernel_slip.MAX_SWITCHES + 1, 8))
                args = (time[i], time[i + 1], np.zeros(0), y, np.int64(modes[i]), float(sigmas[i]), scene.dt, math.inf,
                        y1, np.int64(0), *arrays, rows, np.int64(0))  # fmt: skip
                # (_event_step: the profiles through the dispatcher, event_step reads them into scalars: the same floats)
                ret = (kernel_slip.event_step(*args) if fresh
                       else kernel_slip._event_step(*args[:16], *[kernel_slip.DISPATCHED] * 2, *args[16:], wf, wc))
                got.append((ret, y.tobytes(), rows.tobytes()))
                kinds.update(rows[: ret[2], 1].tolist())
            assert got[0] == got[1], (method, i)
        assert kinds == {0.0, 1.0} and switch.size >= 20, (method, kinds, switch.size)
