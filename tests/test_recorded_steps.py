"""A torque recorded at the step rate: every step clamped at its samples, a run of them one compiled call (the
explicit loop reading each step's own clamps), bit for bit as the same plan stepped one step at a time."""

import numpy as np
import pytest

from belt_drive_ros.core.accuracy_probes import _survey_step
from belt_drive_ros.core.model import make_model
from belt_drive_ros.core.simulate import Simulator
from belt_drive_ros.io.bags import reference_scene
from belt_drive_ros.io.torque_bag import RecordedTorque


def _recorded(n=1500, rate=1000.0, jitter_ns=0):
    """An engine-like torque sampled at ``rate`` [Hz] (times in whole ns, as a bag's), every value different."""
    t_ns = np.round(np.arange(n) / rate * 1e9).astype(np.int64)
    if jitter_ns:
        t_ns[1:] += np.random.default_rng(1).integers(-jitter_ns, jitter_ns + 1, n - 1)
    t = t_ns * 1e-9
    return RecordedTorque(times=t, values=15.0 + 300.0 * np.sin(230.0 * t) + 90.0 * np.sin(460.0 * t))


def _stepper(method, drive, dt=1e-3):
    scene = reference_scene("engine_idle")
    sim = Simulator(make_model("flexible", scene.params), drive, scene.load, method, dt, check_stability=False)
    return sim.stepper, scene.initial_state.vector("flexible", scene.params.ratio)


def _run(method, drive, dt=1e-3, t1=1.2):
    st, x0 = _stepper(method, drive, dt)
    plan = st._plan(0.0, t1)
    times, states = st.run(x0, 0.0, t1)
    return plan, times, states, st.advance(x0, 0.0, t1)


def _one_by_one(st, x0, t0, t1):
    """The plan ``st.steps(t0, t1)`` stepped one step at a time (one kernel call per step or piece, its own clamps)."""
    times, steps = st.steps(t0, t1)
    states = [np.asarray(x0, dtype=float)]
    for a, e, whole, lo, hi, cuts in steps:
        states.append(st._special_step(states[-1], a, e, whole, lo, hi, list(cuts)))
    return times, np.array(states)


@pytest.mark.parametrize("method", ["etd4", "exact", "rk4", "lawson5", "trapezoidal"])
@pytest.mark.parametrize("dt", [1e-3, 5e-4])
def test_steps_clamped_at_recorded_samples_are_the_steps_one_by_one(method, dt):
    drive = _recorded()
    plan, times, states, x_end = _run(method, drive, dt)
    # every step touching a sample clamped (its own bounds, in the plan's arrays), none split
    assert plan["clamps"][0].size >= 1200 - 2 and not plan["splits"]
    st, x0 = _stepper(method, drive, dt)
    ref_times, ref_states = _one_by_one(st, x0, 0.0, 1.2)
    np.testing.assert_array_equal(times, ref_times)
    np.testing.assert_array_equal(states, ref_states)  # the same floats, not merely close
    np.testing.assert_array_equal(x_end, ref_states[-1])
    # from and to times off the grid: partial steps at the ends, the clamped ones between in compiled runs
    np.testing.assert_array_equal(st.advance(x0, 0.0004321, 1.1234567), _one_by_one(st, x0, 0.0004321, 1.1234567)[1][-1])


def test_off_grid_samples_split_their_steps():
    """Jittered receive times (off the step grid): steps are split at them, the same states as one by one."""
    drive = _recorded(jitter_ns=20_000)
    plan, _, states, _ = _run("etd4", drive)
    assert len(plan["splits"]) > 800  # (a cell may hold two cuts, another none)
    st, x0 = _stepper("etd4", drive)
    np.testing.assert_array_equal(states, _one_by_one(st, x0, 0.0, 1.2)[1])


def test_a_linear_table_read_at_each_steps_end():
    """A linear table (a kink per sample): the step ending at a sample reads its left limit there; the same floats."""
    from belt_drive_ros.core.sources import Table

    t = np.arange(1500) * 1e-3
    drive = Table(times=t, values=15.0 + 300.0 * np.sin(230.0 * t), interpolation="linear")
    for method in ("etd4", "exact"):
        _, _, states, _ = _run(method, drive)
        st, x0 = _stepper(method, drive)
        np.testing.assert_array_equal(states, _one_by_one(st, x0, 0.0, 1.2)[1])


def test_the_rigid_survey_steps_at_a_dense_records_rate():
    bps = np.asarray(_recorded(6000).breakpoints())
    assert _survey_step(lambda: [bps], 5e-3) == 1e-3  # 1 kHz record, survey step 5 ms: at the record's rate
    assert _survey_step(lambda: [bps[::10]], 5e-3) == 5e-3  # sparser than the survey step: unchanged
    jittered = np.asarray(_recorded(6000, jitter_ns=20_000).breakpoints())
    assert _survey_step(lambda: [jittered], 5e-3) == 5e-3  # not on a grid: unchanged


def test_clamped_runs_add_no_compiled_specialisation():
    from belt_drive_ros.core import kernel, kernel_profiles

    _run("etd4", _recorded())
    _run("trapezoidal", _recorded())
    assert len(kernel.clamped_steps.signatures) == 1  # (the runs' one call; the others are called from compiled code)
    assert all(len(f.signatures) <= 1 for f in (kernel.linear_steps, kernel._explicit, kernel_profiles.profile_torque_array))


def test_clamped_steps_interpreted_give_the_same_floats():
    """NUMBA_DISABLE_JIT=1: the clamped run (the explicit loop reading each step's clamps) interpreted, the same
    states as compiled."""
    import os
    import subprocess
    import sys

    code = (
        "import sys; sys.path.insert(0, %r); import numpy as np; import test_recorded_steps as T; "
        "_, _, x, _ = T._run('etd4', T._recorded(300), t1=0.25); sys.stdout.write(x.tobytes().hex())"
    ) % os.path.dirname(__file__)
    out = {}
    for jit in ("0", "1"):
        env = dict(os.environ, NUMBA_DISABLE_JIT=jit)
        out[jit] = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True).stdout
    assert out["0"] and out["0"] == out["1"]
