"""The ensemble core against single runs: batched schemes, batched exponentials, whole runs.

Each variant of an ensemble must give what ``simulate`` gives for it alone.
The reference is always the single run (the stepper's compiled loop), never
the ensemble itself.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg

from belt_drive_ros.core.batch_expm import expm_stack
from belt_drive_ros.core.ensemble import Ensemble, EnsembleUnsupported
from belt_drive_ros.campaign.ensemble_run import GroupRun, GroupSummary, peak_over_time, run_groups, simulate_many
from belt_drive_ros.core.integrators import REGISTRY
from belt_drive_ros.core.kernel_loop import OK
from belt_drive_ros.core.model import ModelStack, make_model
from belt_drive_ros.io.scenes import load_scene
from belt_drive_ros.core.scene import shipped_scenes
from belt_drive_ros.core.simulate import simulate

#: relative agreement of an ensemble variant's states and outputs with its single run (norm-wise over the trajectory).
#: Both step with the same matrices (one exponential routine) summed in the same order, so in practice they
#: agree bit for bit; the bound is the issue's.
STATE_RTOL = 1e-12


def _variants(scene, count: int, seed: int):
    """``count`` copies of ``scene`` with belt stiffness, damping, inertias, pre-tension and start speed perturbed."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(count):
        p = scene.params
        params = p.replace(
            k=p.k * (1 + 0.1 * rng.standard_normal()), c=p.c * rng.uniform(0.5, 1.5), I_3=p.I_3 * rng.uniform(0.8, 1.2),
            I_M=p.I_M * rng.uniform(0.8, 1.2), F_0=p.F_0 * rng.uniform(0.9, 1.1),
        )  # fmt: skip
        init = scene.initial_state.__class__(
            phi_M=scene.initial_state.phi_M, omega_M=scene.initial_state.omega_M * rng.uniform(0.95, 1.05),
            relative_deflection=scene.initial_state.relative_deflection, relative_speed=scene.initial_state.relative_speed,
        )  # fmt: skip
        out.append(scene.with_overrides(params=params, initial_state=init))
    return out


def _state_error(a: np.ndarray, b: np.ndarray) -> float:
    """max |a - b| / max |b| over the trajectory (norm-wise relative; 0 when both are all zero)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    scale = np.max(np.abs(b))
    return float(np.max(np.abs(a - b)) / scale) if scale > 0 else float(np.max(np.abs(a)))


def _assert_equal_to_single(result, single) -> None:
    """The ensemble's states, inputs and every output agree with the single run to STATE_RTOL."""
    assert _state_error(result.states, single.states) <= STATE_RTOL
    assert _state_error(result.inputs, single.inputs) <= STATE_RTOL
    for signal, values in single.outputs.items():
        got = np.asarray(result.outputs[signal])
        assert got.shape == np.asarray(values).shape, signal
        assert _state_error(got, values) <= STATE_RTOL, signal


def test_expm_stack_equals_scipy_per_matrix():
    rng = np.random.default_rng(0)
    A = rng.standard_normal((50, 6, 6)) * rng.uniform(0.01, 3.0, (50, 1, 1))
    E = expm_stack(A)
    for a, e in zip(A, E):
        ref = scipy.linalg.expm(a)
        assert np.max(np.abs(e - ref)) <= 1e-13 * np.max(np.abs(ref))
    jordan = np.array([[0.0, 1.0], [0.0, 0.0]]) * 7.0  # the rigid-body mode's defective block: e^J = I + J
    assert np.max(np.abs(expm_stack(jordan[None])[0] - (np.eye(2) + jordan))) <= 1e-14 * 7.0


@pytest.mark.parametrize("method", [n for n, c in REGISTRY.items() if c.fixed_step])
def test_batched_stage_scheme_is_each_variants_scheme(method):
    scene = load_scene("truck_compressor")
    models = [make_model("flexible", s.params) for s in _variants(scene, 4, seed=1)]
    A, B = np.stack([m.A for m in models]), np.stack([m.B for m in models])
    batched = REGISTRY[method](A, B, 5e-4).scheme
    for v, m in enumerate(models):
        single = REGISTRY[method](m.A, m.B, 5e-4).scheme
        assert batched.nodes == single.nodes and batched.final_base == single.final_base
        pairs = [(batched.final[v], single.final)] + [(b[v], s) for b, s in zip(batched.stages, single.stages) if s is not None]
        assert [s is None for s in batched.stages] == [s is None for s in single.stages]
        for b, s in pairs:
            assert b.shape == s.shape
            assert np.max(np.abs(b - s)) <= 1e-13 * np.max(np.abs(s))  # batched Pade vs scipy's expm: rounding


@pytest.mark.parametrize("name", shipped_scenes())
@pytest.mark.parametrize("model", ["rigid", "flexible"])
def test_ensemble_equals_single_runs_on_every_shipped_scene(name, model):
    scene = load_scene(name).with_overrides(model=model, duration=min(load_scene(name).duration, 1.0))
    scenes = _variants(scene, 9, seed=hash((name, model)) % 1000)
    outcomes = sorted(simulate_many(scenes), key=lambda o: o.index)
    assert all(o.ensemble and o.error is None for o in outcomes)
    for outcome, s in zip(outcomes, scenes):
        single = simulate(s)
        got = outcome.result
        assert got.model == single.model == model
        assert np.array_equal(got.time, single.time)  # the stepper's own knots
        _assert_equal_to_single(got, single)


@pytest.mark.parametrize("name", shipped_scenes())
def test_auto_choice_in_the_ensemble_is_the_single_runs(name):
    """model auto: the same tier per variant (rigid, flexible, or slipping run singly) and the same reason."""
    scene = load_scene(name).with_overrides(duration=min(load_scene(name).duration, 0.6))
    scenes = _variants(scene, 8, seed=7)
    outcomes = sorted(simulate_many(scenes), key=lambda o: o.index)
    for outcome, s in zip(outcomes, scenes):
        single = simulate(s)
        assert outcome.error is None
        assert outcome.result.model == single.model
        assert outcome.result.choice.reason.split(":")[0] == single.choice.reason.split(":")[0]
        assert outcome.ensemble == (single.model != "slipping")
        if outcome.ensemble:
            _assert_equal_to_single(outcome.result, single)
        else:
            assert "slipping" in outcome.single_reason


def test_a_failing_variant_is_reported_and_the_others_run():
    scene = load_scene("truck_compressor").with_overrides(model="flexible", method="rk4", dt=2e-3, duration=0.2)
    good = _variants(scene.with_overrides(params=scene.params.replace(k=2e4)), 8, seed=3)
    stiff = scene.with_overrides(params=scene.params.replace(k=3e6))  # rk4 at 2 ms cannot hold this belt mode
    outcomes = sorted(simulate_many([*good, stiff]), key=lambda o: o.index)
    assert [o.error is None for o in outcomes] == [True] * 8 + [False]
    assert outcomes[-1].error.startswith("UnstableStepError") and "rk4" in outcomes[-1].error
    with pytest.raises(Exception) as single:
        simulate(stiff)
    assert str(single.value) in outcomes[-1].error


def test_methods_the_ensemble_does_not_cover_run_singly():
    scene = load_scene("paper").with_overrides(model="flexible", method="RK45", dt=0.01, duration=0.3)
    outcomes = list(simulate_many(_variants(scene, 8, seed=4)))
    assert all(not o.ensemble and o.error is None and "adaptive" in o.single_reason for o in outcomes)
    with pytest.raises(EnsembleUnsupported, match="implicit"):
        Ensemble(ModelStack("flexible", [scene.params]), scene.drive, scene.load, "trapezoidal", 0.01)


def test_truck_compressor_flexible_over_its_whole_duration():
    """The scene whose closed loop amplifies rounding most (firing torque at the crank angle, a governor): 3 s."""
    scene = load_scene("truck_compressor").with_overrides(model="flexible")
    scenes = _variants(scene, 8, seed=11)
    outcomes = sorted(simulate_many(scenes), key=lambda o: o.index)
    for outcome, s in zip(outcomes, scenes):
        assert outcome.ensemble and outcome.error is None
        _assert_equal_to_single(outcome.result, simulate(s))


def test_expm_of_a_matrix_does_not_depend_on_its_stack():
    """What makes single runs and ensembles step with the same matrices: e^A[k] depends on A[k] alone, bit for bit."""
    rng = np.random.default_rng(3)
    A = rng.standard_normal((40, 8, 8)) * rng.uniform(0.001, 40.0, (40, 1, 1))  # every Pade degree and scaling
    E = expm_stack(A)
    for a, e in zip(A, E):
        assert np.array_equal(expm_stack(a), e)


@pytest.mark.parametrize("name", ["paper", "truck_compressor", "bsg_start"])
def test_windows_are_the_whole_run_and_reductions_over_them_its_reductions(name):
    """Ensemble.windows gives run()'s knots and states bit for bit; run_groups(reduce=...) over windows of 23 steps
    gives per variant what the whole run's arrays reduce to (max, min, first, last, first argmax), with the same
    model choices (auto) and the same outcomes."""
    scene = load_scene(name).with_overrides(duration=min(load_scene(name).duration, 0.5))
    scenes = _variants(scene, 9, seed=13)
    ens = Ensemble(ModelStack("flexible", [s.params for s in scenes]), scene.drive, scene.load, scene.method, scene.dt)
    x0 = np.stack([s.initial_state.vector("flexible", s.params.ratio) for s in scenes])
    times, states = ens.run(x0, 0.0, scene.duration)
    parts = list(ens.windows(x0, 0.0, scene.duration, 23))  # kept as yielded: a later window writes no earlier one
    assert len(parts) > 2 and all(np.array_equal(a[0][-1], b[0][0]) for a, b in zip(parts, parts[1:]))
    assert np.array_equal(np.concatenate([parts[0][0]] + [t[1:] for t, _ in parts[1:]]), times)
    assert np.array_equal(np.concatenate([parts[0][1]] + [x[1:] for _, x in parts[1:]]), states)

    def window(run):
        belt = run.output("belt_torque")
        return {"peak": np.max(np.abs(belt), axis=0), "low": np.min(run.output("omega_M"), axis=0),
                "first": belt[0], "last": belt[-1], "at": peak_over_time(np.abs(belt), run.times)}  # fmt: skip

    kinds = {"peak": "max", "low": "min", "first": "first", "last": "last", "at": "argmax"}
    for model_name in ("flexible", "auto"):
        group = [s.with_overrides(model=model_name) for s in scenes]
        whole = {o.indices[0] if hasattr(o, "indices") else o.index: o for o in run_groups(group)}
        reduced = {o.indices[0] if hasattr(o, "indices") else o.index: o for o in run_groups(group, reduce=(kinds, window), window=23)}
        assert whole.keys() == reduced.keys()
        for key, full in whole.items():
            summary = reduced[key]
            if isinstance(full, GroupRun):
                assert isinstance(summary, GroupSummary) and summary.indices == full.indices and summary.kind == full.kind
                expected = window(full)
                for k in ("peak", "low", "first", "last"):
                    assert np.array_equal(summary.values[k], expected[k]), k
                assert all(np.array_equal(a, b) for a, b in zip(summary.values["at"], expected["at"]))
                assert [c.reason if c else None for c in summary.choices] == [c.reason if c else None for c in full.choices]
            else:
                assert (summary.index, summary.error, summary.single_reason) == (full.index, full.error, full.single_reason)


@pytest.mark.parametrize("kind", ["rigid", "flexible"])
def test_model_stack_is_each_variants_model(kind):
    """ModelStack builds V models' matrices at once from parameter columns: each is make_model's, bit for bit
    (zero signs included), also for undamped belts and bearings; the derived parameters are each variant's own."""
    from belt_drive_ros.core.model import ModelStack
    from belt_drive_ros.core.params import ParamColumns

    rng = np.random.default_rng(21)
    params = []
    for name in shipped_scenes():
        p = load_scene(name).params
        params += [p.replace(k=p.k * rng.uniform(0.5, 2), c=p.c * rng.uniform(0, 2), I_3=p.I_3 * rng.uniform(0.5, 2),
                             I_1=p.I_1 * rng.uniform(0, 2), b_3=p.b_3 * rng.uniform(0, 2), r_2=p.r_2 * rng.uniform(0.8, 1.2),
                             R_1=p.R_1 * rng.uniform(0.8, 1.2)) for _ in range(6)]  # fmt: skip
        params.append(p.replace(c=0.0, b_M=0.0, b_1=0.0, b_2=0.0, b_3=0.0))
    stack = ModelStack(kind, params)
    columns = ParamColumns(params)
    for v, p in enumerate(params):
        model = make_model(kind, p)
        for name in ("A", "B", "C", "D"):
            got, want = getattr(stack, name)[v], getattr(model, name)
            assert np.array_equal(got, want) and np.array_equal(np.signbit(got), np.signbit(want)), name
        assert np.array_equal(stack.W[v], model.wheel_map)
        for name in ("ratio", "inertia_reduced", "bearing_damping_drive_side", "belt_torsional_stiffness"):
            assert getattr(columns, name)[v] == getattr(p, name)
    keep = [3, 0, 5]
    part = stack.subset(keep)
    assert np.array_equal(part.A, stack.A[keep]) and part.model(1).params == params[0]


@pytest.mark.parametrize("name", ["paper", "bsg_start", "e_motor_start", "truck_compressor"])
def test_each_variant_is_its_single_run_bit_for_bit(name):
    """The ensemble runs the single run's own compiled loop per variant: the very same floats (states and knots),
    steps split and clamped at torque breakpoints included."""
    scene = load_scene(name)
    scene = scene.with_overrides(model="flexible", duration=min(scene.duration, 0.4))
    scenes = _variants(scene, 8, seed=11)
    outcomes = sorted(simulate_many(scenes), key=lambda o: o.index)
    assert all(o.ensemble and o.error is None for o in outcomes)
    for outcome, s in zip(outcomes, scenes):
        single = simulate(s)
        assert np.array_equal(outcome.result.time, single.time)
        assert np.array_equal(outcome.result.states, single.states), s.name


@pytest.mark.parametrize("name", ["paper", "truck_compressor"])
def test_variants_stepped_as_lanes_are_their_single_runs_bit_for_bit(name):
    """A 4-state explicit method steps the variants in chunks of LANES as vector lanes
    (kernel_variants._lanes): more than one chunk, rigid (2 states) and flexible (4), every explicit method (one
    stage, stage maps, a stage that starts the final map), torques that read their angle (truck_compressor) or not
    (paper), and a variant that diverges mid-chunk: every other variant's knots equal its single run's, the
    diverged one NaN after its bad knot."""
    from belt_drive_ros.core.kernel_variants import LANES
    from belt_drive_ros.core.model import ModelStack
    from belt_drive_ros.core.stepper import Plant, Stepper

    scene = load_scene(name)
    count = LANES + 7
    params = [s.params for s in _variants(scene, count, seed=13)]
    for kind, method in [("rigid", "exact"), ("rigid", "rk4")] + [
        ("flexible", m) for m in ("exact", "euler", "symplectic_euler", "rk4", "etd2", "etd4", "lawson5")
    ]:
        chosen = list(params)
        if method == "euler":
            chosen[LANES - 3] = chosen[LANES - 3].replace(k=5e6)  # euler: the belt mode grows without bound
        ens = Ensemble(ModelStack(kind, chosen), scene.drive, scene.load, method, 2e-3)
        x0 = np.zeros((count, 2 if kind == "rigid" else 4))
        x0[:, 1] = 1.0
        times, states = ens.run(x0, 0.0, 0.1)
        bad = ens.first_bad(times, states, {})
        assert (LANES - 3 in bad) if method == "euler" else not bad, method  # (euler: truck_compressor's all diverge)
        for v in range(count):
            if v in bad:  # NaN after the first bad knot (written as the single loop wrote it)
                k = int(np.searchsorted(times, bad[v][0]))
                assert 0 < k < len(times) - 1 and np.isnan(states[k + 1 :, :, v]).all()
                continue
            stepper = Stepper(Plant(make_model(kind, chosen[v]), scene.drive, scene.load), method, 2e-3)
            t1, x1 = stepper.run(x0[v], 0.0, 0.1)
            assert np.array_equal(t1, times)
            assert np.array_equal(x1, states[:, :, v]), (kind, method, v)


def test_a_diverging_variant_is_found_and_the_others_step_on():
    """A variant whose state leaves the plausible range gets NaN knots after its first bad one (found, reported
    as the single run reports it); the others are untouched, across windows."""
    from belt_drive_ros.core.model import ModelStack

    scene = load_scene("paper").with_overrides(model="flexible", method="euler", dt=5e-3, duration=1.0)
    params = [v.params for v in _variants(scene, 4, seed=2)]
    params[2] = params[2].replace(k=5e6)  # euler at 5 ms: the belt mode grows without bound
    ens = Ensemble(ModelStack("flexible", params), scene.drive, scene.load, "euler", scene.dt)
    times, states = ens.run(np.zeros((4, 4)), 0.0, scene.duration)
    found: dict = {}
    for t, s in ens.windows(np.zeros((4, 4)), 0.0, scene.duration, 16):
        ens.first_bad(t, s, found)
    assert list(found) == [2] and list(ens.diverged_errors(ens.first_bad(times, states, {}))) == [2]
    # the compiled loop's own status says the same (campaigns look for bad knots only in windows after it did)
    assert [v for v in range(4) if ens.status[v] != OK] == [2]
    assert np.isnan(states[-1, :, 2]).all()
    for v in (0, 1, 3):
        alone = Ensemble(ModelStack("flexible", [params[v]]), scene.drive, scene.load, "euler", scene.dt)
        assert np.array_equal(alone.run(np.zeros((1, 4)), 0.0, scene.duration)[1][:, :, 0], states[:, :, v])


def test_the_variant_kernel_compiles_once_and_runs_interpreted_alike(tmp_path):
    """One compiled specialisation of the variant loop whatever the scene; NUMBA_DISABLE_JIT=1 gives the same floats."""
    import os
    import subprocess
    import sys

    from belt_drive_ros.core import kernel, kernel_variants

    for name in ("paper", "bsg_start", "truck_compressor"):
        scene = load_scene(name).with_overrides(model="flexible", duration=0.05)
        list(simulate_many(_variants(scene, 8, seed=5)))
    assert len(kernel_variants.variant_steps.signatures) == 1
    assert len(kernel_variants.knot_torques.signatures) == 1
    assert len(kernel.linear_steps.signatures) == 1
    code = (
        "import sys, numpy as np\n"
        "from belt_drive_ros.core.ensemble import Ensemble\n"
        "from belt_drive_ros.core.model import ModelStack\n"
        "from belt_drive_ros.io.scenes import load_scene\n"
        "s = load_scene('paper')\n"
        "ps = [s.params.replace(k=s.params.k * f) for f in (0.9, 1.0, 1.1)]\n"
        "e = Ensemble(ModelStack('flexible', ps), s.drive, s.load, 'lawson5', s.dt)\n"
        "t, x = e.run(np.zeros((3, 4)), 0.0, 0.1)\n"
        "np.save(sys.argv[1], np.concatenate([x, e.inputs(t, x)], axis=1))\n"
    )
    states = {}
    for jit in ("0", "1"):
        path = tmp_path / f"states_{jit}.npy"
        env = dict(os.environ, NUMBA_DISABLE_JIT=jit)
        done = subprocess.run([sys.executable, "-c", code, str(path)], env=env, capture_output=True, text=True, timeout=600)
        assert done.returncode == 0, done.stderr
        states[jit] = np.load(path)
    assert states["0"].shape == (21, 6, 3)  # the states and the knots' torques
    assert np.array_equal(states["0"], states["1"])


def test_auto_in_the_ensemble_sees_a_torque_that_changes_with_the_speed():
    """A motor curve cut from 60 to 0 N m within 5 rad/s: simulate runs it flexible (the rigid run's fastest
    belt-torque change, 72 Hz against a 162 Hz belt); the campaign's ensemble chose rigid for every variant (its
    rigid estimate gave the rule no change frequency). The ensemble's estimate records it too: the same tier, and
    the variants equal their single runs."""
    from test_fidelity_reason import _speed_limited

    scenes = _variants(_speed_limited(5.0).with_overrides(duration=0.6), 4, seed=3)
    outcomes = sorted(simulate_many(scenes), key=lambda o: o.index)
    for outcome, s in zip(outcomes, scenes):
        single = simulate(s)
        assert single.model == "flexible" and "fastest belt-torque change" in single.choice.reason
        assert outcome.error is None and outcome.result.model == "flexible"
        _assert_equal_to_single(outcome.result, single)
