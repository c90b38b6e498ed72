"""A torque recorded at the step rate: steps absorbed into runs of whole steps, bit for bit as planned one by one."""

import numpy as np
import pytest

from belt_drive_ros.core import step_plan as S
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


def _run(method, drive, dt=1e-3, absorb_min=S.ABSORB_MIN, t1=1.2):
    scene = reference_scene("engine_idle")
    mdl = make_model("flexible", scene.params)
    sim = Simulator(mdl, drive, scene.load, method, dt, check_stability=False)
    x0 = scene.initial_state.vector("flexible", scene.params.ratio)
    old, S.ABSORB_MIN = S.ABSORB_MIN, absorb_min
    try:
        plan = sim.stepper._plan(0.0, t1, absorb=True)
        times, states = sim.stepper.run(x0, 0.0, t1)
        x_end = sim.stepper.advance(x0, 0.0, t1)
    finally:
        S.ABSORB_MIN = old
    return plan, times, states, x_end


@pytest.mark.parametrize("method", ["etd4", "exact", "rk4", "lawson5"])
@pytest.mark.parametrize("dt", [1e-3, 5e-4])
def test_steps_next_to_recorded_samples_are_absorbed_bit_for_bit(method, dt):
    drive = _recorded()
    plan, times, states, x_end = _run(method, drive, dt)
    # every step but the two at the ends runs in the absorbed loop: no special (clamped) step left inside
    assert plan["absorbed"].size >= round(1.2 / dt) - 4
    assert plan["clamps"][0].size <= 4 and not plan["splits"]
    ref_plan, ref_times, ref_states, ref_end = _run(method, drive, dt, absorb_min=10**12)
    assert ref_plan["absorbed"].size == 0 and ref_plan["clamps"][0].size > 1000
    np.testing.assert_array_equal(times, ref_times)
    np.testing.assert_array_equal(states, ref_states)  # the same floats, not merely close
    np.testing.assert_array_equal(x_end, ref_end)


def test_off_grid_samples_are_planned_as_before():
    """Jittered receive times (off the step grid): steps are split at them, nothing absorbed, same states."""
    drive = _recorded(jitter_ns=20_000)
    plan, _, states, _ = _run("etd4", drive)
    assert plan["absorbed"].size == 0  # nothing on the grid to absorb
    _, _, ref_states, _ = _run("etd4", drive, absorb_min=10**12)
    np.testing.assert_array_equal(states, ref_states)


def test_a_step_whose_clamp_changes_a_torque_is_not_absorbed():
    """A linear table (a kink per sample) reads a different torque 1 ns before the step's end: planned as before."""
    from belt_drive_ros.core.sources import Table

    t = np.arange(1500) * 1e-3
    drive = Table(times=t, values=15.0 + 300.0 * np.sin(230.0 * t), interpolation="linear")
    plan, _, states, _ = _run("etd4", drive)
    assert plan["absorbed"].size == 0
    _, _, ref_states, _ = _run("etd4", drive, absorb_min=10**12)
    np.testing.assert_array_equal(states, ref_states)
    plan, _, states, _ = _run("exact", drive)  # ... but exact samples at the step's start only: absorbed
    assert plan["absorbed"].size > 1000
    _, _, ref_states, _ = _run("exact", drive, absorb_min=10**12)
    np.testing.assert_array_equal(states, ref_states)


def test_the_rigid_survey_steps_at_a_dense_records_rate():
    bps = np.asarray(_recorded(6000).breakpoints())
    assert _survey_step(lambda: [bps], 5e-3) == 1e-3  # 1 kHz record, survey step 5 ms: at the record's rate
    assert _survey_step(lambda: [bps[::10]], 5e-3) == 5e-3  # sparser than the survey step: unchanged
    jittered = np.asarray(_recorded(6000, jitter_ns=20_000).breakpoints())
    assert _survey_step(lambda: [jittered], 5e-3) == 5e-3  # not on a grid: unchanged


def test_absorbing_adds_no_compiled_specialisation():
    from belt_drive_ros.core import kernel, kernel_profiles

    _run("etd4", _recorded())
    assert len(kernel.linear_steps.signatures) == 1 and len(kernel_profiles.profile_torque_array.signatures) == 1


def test_absorbed_steps_interpreted_give_the_same_floats():
    """NUMBA_DISABLE_JIT=1: the absorbed run (its check and its loop) interpreted, the same states as compiled."""
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
