"""The slipping tier of belt networks (core/network/slip.py, slip_kernel.py): stick/slip at every pulley.

Each check against a reference written here: the capstan onset per pulley against its closed form from
the statics of a loop; the energy balance of an undamped run; the paper's drive as a network against the
single-belt slipping model (core/slip.py); several pulleys sliding at once; a belt that never reaches
the limit against the linear tier; the kernel interpreted (NUMBA_DISABLE_JIT=1) against compiled.
"""

from __future__ import annotations

import dataclasses
import math
from importlib import resources

import numpy as np
import pytest

from belt_drive_ros.core.errors import SceneError
from belt_drive_ros.io.inputs import parse_yaml
from belt_drive_ros.core.network.model import NetworkModel
from belt_drive_ros.core.network.simulate import simulate as simulate_linear
from belt_drive_ros.core.network.scene import NetworkScene
from belt_drive_ros.io.scenes import load_network
from belt_drive_ros.core.network.slip import simulate_slipping

R = 0.05  # every pulley of the square loop
SIDE = 0.3


def square(torques, mus, T0=300.0, damping=2.0, EA=2.0e4, inertia=(0.05, 0.01, 0.01, 0.002), duration=1.0, dt=1e-3,
           bearing=0.0):
    """Four pulleys of radius R at the corners of a square (driver, accessory a, accessory b, idler; wraps pi/2)."""
    return NetworkScene.from_mapping({
        "kind": "network", "duration": duration, "dt": dt, "initial_speed": 0.0,
        "belt": {"EA": EA, "damping": damping, "installed_tension": T0},
        "pulleys": _square_pulleys(torques, mus, inertia, bearing),
    })  # fmt: skip


def _square_pulleys(torques, mus, inertia=(0.05, 0.01, 0.01, 0.002), bearing=0.0) -> list:
    """The square loop's pulleys as a scene's ``pulleys`` list (:func:`square`)."""
    names = ("driver", "acc_a", "acc_b", "idler")
    roles = ("driver", "accessory", "accessory", "idler")
    centres = ((0.0, 0.0), (SIDE, 0.0), (SIDE, SIDE), (0.0, SIDE))
    pulleys = []
    for i in range(4):
        p = {"name": names[i], "role": roles[i], "centre": list(centres[i]), "radius": R, "inertia": inertia[i],
             "mu": mus[i], "damping": bearing}
        if torques[i] is not None:
            p["torque"] = torques[i]
        pulleys.append(p)
    return pulleys


def shipped(name):
    """A shipped network scene's mapping (to change before building it)."""
    return parse_yaml((resources.files("belt_drive_ros") / "scenes" / "networks" / f"{name}.yaml").read_text(), name)


def ramp(top, end=2.0):
    return {"type": "ramp", "start_value": 0.0, "end_value": top, "start_time": 0.0, "end_time": end}


# ----------------------------------------------------------------------------- capstan onset
@pytest.mark.parametrize("which", [0, 1, 2])
def test_capstan_onset_per_pulley_against_its_closed_form(which):
    """A drive torque M(t) ramped slowly, the accessories' loads 0.6 M and 0.4 M balancing it (no acceleration):
    the loop's statics by hand give the tensions, and the pulley with the small mu starts to slip where
    ``|T_i - T_{i-1}| = tanh(mu_i beta_i / 2) (T_i + T_{i-1})``.

    Statics of a loop without tensioner: each pulley ``T_i - T_{i-1} = -Q_i / r_i``; the stretches go once
    round the loop, ``sum_j (T_j - T_0) L_j / EA = 0``. Quasi-static: the ramp (2 s) is slow against the
    belt modes (>= 20 Hz), so the onset time agrees to 1e-3 (the damped spans lag by c delta').
    """
    top, end = 40.0, 20.0  # N m at t = 20 s
    mus = [2.0, 2.0, 2.0, 2.0]
    mus[which] = 0.25
    scene = square([ramp(top, end), ramp(0.6 * top, end), ramp(0.4 * top, end), None], mus, duration=10.0, bearing=0.05)
    run = simulate_slipping(None, scene)
    assert run.events, "the ramp must reach the capstan limit"
    first = run.events[0]
    assert first.kind == "onset" and first.pulley == scene.pulleys[which].name
    # tensions per unit drive torque: tau_j with T_j = T_0 + M tau_j
    Q = np.array([1.0, -0.6, -0.4, 0.0])  # signed torques per unit M (+ drives)
    diff = -Q / R  # T_i - T_{i-1}
    L = scene.geometry.lengths
    tau = np.zeros(4)
    for i in range(1, 4):
        tau[i] = tau[i - 1] + diff[i]
    tau -= np.dot(L, tau) / L.sum()  # sum_j L_j tau_j = 0
    i, p = which, (which - 1) % 4
    d, s = tau[i] - tau[p], tau[i] + tau[p]
    f = math.tanh(0.5 * mus[i] * scene.geometry.wraps[i])
    M_star = 2.0 * f * scene.belt.installed_tension / (abs(d) - f * s)
    t_star = M_star / (top / end)
    assert first.time == pytest.approx(t_star, rel=1e-3)
    assert first.direction == (1 if d > 0 else -1)
    # friction use reaches 1 there, and not before
    k = int(first.time / scene.dt)
    assert run.friction_use[k - 1, which] < 1.0 and run.friction_use[k + 2, which] == pytest.approx(1.0, abs=1e-9)


# ----------------------------------------------------------------------------- energy
def energies(scene, model, run):
    """Kinetic and potential energy per sample [J]: 1/2 J omega^2, 1/2 sum k_j delta_j^2 + 1/2 k_arm theta_a^2."""
    m, n = model.M.shape[0], len(scene.pulleys)
    q, qd = run.states[:, :m], run.states[:, m:]
    s = run.slip_distance
    kinetic = 0.5 * (qd**2) @ np.diag(model.M)
    delta = q @ model.stretch.T + np.roll(s, -1, axis=1) - s
    potential = 0.5 * (delta**2) @ model.k
    if model.arm >= 0:
        k_arm = model.stiffness()[model.arm, model.arm] - (model.stretch[:, model.arm] ** 2) @ model.k
        potential = potential + 0.5 * k_arm * q[:, model.arm] ** 2
    return kinetic, potential


def test_energy_balance_of_an_undamped_run():
    """Undamped spans, bearings and arm: the work of the torques equals kinetic + stored energy + the friction
    loss ``int sum_i (T_i - T_{i-1}) s_i' dt`` (>= 0), sample by sample.

    The work of a torque held over a step is exact (``u Delta theta``); the friction loss is Simpson's rule
    over each (sub-)step, error O(h^5) per step: the balance holds to 1e-7 of the work done.
    """
    scene = square([{"type": "constant", "value": 30.0}, {"type": "constant", "value": 10.0},
                    {"type": "constant", "value": 5.0}, None], [0.3, 0.3, 0.3, 0.3], damping=0.0, duration=0.5)
    model = NetworkModel.build(scene)
    run = simulate_slipping(model, scene)
    assert len(run.events) >= 2, "the run must slip"
    work = run.input_work.sum(axis=1)
    loss = run.friction_work.sum(axis=1)
    kinetic, potential = energies(scene, model, run)
    stored = kinetic + potential - kinetic[0] - potential[0]
    assert loss[-1] > 0.01 * work[-1] and np.all(np.diff(loss) >= -1e-12 * work[-1])
    assert np.max(np.abs(work - stored - loss)) <= 1e-7 * np.max(np.abs(work))


# ----------------------------------------------------------------------------- the single-belt model
def test_paper_network_that_slips_matches_the_single_belt_slipping_model():
    """``paper_network`` at installed tension 100 N (the soft start slips pulley 3, which re-sticks as the drive
    settles) against ``core/slip.py`` on the ``paper`` scene's parameters with ``F_0 = 100`` and pulley 3's wrap,
    both ``exact`` at 1 ms.

    The same equations in different coordinates (5 states there; 6 here: the rigid turning kept, both
    pulleys' slip) with different matrix exponentials (scipy's Pade there, a Taylor series here): the
    flows differ by rounding, ~1e-13 relative per step (measured 3e-11 of the peak speed after 2000
    steps: 1e-9 asked). The single belt locates an event to ~1e-15 s; the network kernel halves a step
    down to units of dt / 2^30 and switches one unit past the crossing, so its event times lie up to
    one unit (0.9e-12 s at 1 ms) later: two units asked.
    """
    from belt_drive_ros.io.scenes import load_scene
    from belt_drive_ros.core.slip_run import SlippingSimulator

    data = shipped("paper_network")
    data["belt"]["installed_tension"] = 100.0
    for p in data["pulleys"]:
        p["mu"] = 0.5
    net = NetworkScene.from_mapping(data, "paper_slip")
    run = simulate_slipping(None, net, duration=2.0, dt=1e-3)
    paper = load_scene("paper")
    params = dataclasses.replace(paper.params, F_0=100.0, wrap_angle=float(net.geometry.wraps[1]))
    sim = SlippingSimulator(params, paper.drive, paper.load, "exact", 1e-3)
    time, ys, _, _ = sim.run(2.0, np.zeros(5))
    ref = [(e.time, "onset" if e.kind == "onset" else "restick", int(e.sigma)) for e in sim.events]
    got = [(e.time, e.kind, e.direction if e.kind == "onset" else 0) for e in run.events]
    assert len(ref) >= 2 and [r[1:] for r in ref] == [g[1:] for g in got]
    assert all(e.pulley == "pulley_3" for e in run.events)
    assert run.first_slip() == run.events[0] and run.first_slip().kind == "onset"  # (docs/serpentine.md's call)
    unit = 1e-3 / 2**30
    assert np.max(np.abs(np.array([r[0] for r in ref]) - np.array([g[0] for g in got]))) <= 2 * unit
    grid = np.isclose(time / 1e-3, np.round(time / 1e-3), rtol=0.0, atol=1e-6)  # the single run adds event samples
    k = np.round(time[grid] / 1e-3).astype(int)
    g = paper.params.gear_ratio
    speeds = np.stack([ys[grid, 2] * g, ys[grid, 3]], axis=1)
    assert np.max(np.abs(run.speed[k] - speeds)) <= 1e-9 * np.max(np.abs(speeds))
    assert np.max(np.abs(run.slip_distance[k, 1] - ys[grid, 4])) <= 1e-9 * np.max(np.abs(ys[:, 4]))


# ----------------------------------------------------------------------------- several at once
def test_several_pulleys_slide_at_once_each_at_its_limit():
    """A hard drive step against two accessories with little friction: both slide together for a while; on
    each the tension difference sits at its capstan limit (friction use 1) and the slip speed has the
    direction of ``T_i - T_{i-1}`` (the belt runs ahead where the leaving span is tighter)."""
    scene = square([{"type": "constant", "value": 30.0}, {"type": "constant", "value": 6.0},
                    {"type": "constant", "value": 6.0}, None], [2.0, 0.2, 0.2, 2.0], duration=0.3)
    run = simulate_slipping(None, scene)
    both = (run.slip_state[:, 1] != 0) & (run.slip_state[:, 2] != 0)
    assert both.sum() >= 10
    for i in (1, 2):
        assert np.allclose(run.friction_use[both, i], 1.0, atol=1e-9, rtol=0.0)
        D = run.tension[both, i] - run.tension[both, (i - 1) % 4]
        assert np.all(np.sign(D) == run.slip_state[both, i])
        assert np.all(run.slip_speed[both, i] * run.slip_state[both, i] >= -1e-12)
    onsets = {e.pulley for e in run.events if e.kind == "onset"}
    assert {"acc_a", "acc_b"} <= onsets


def test_within_the_limit_the_slipping_tier_is_the_linear_tier():
    """``fead_i4`` never reaches its capstan limit: the slipping tier (all sticking, exact flow) gives the linear
    tier's exact run. The two exponentials differ (scipy's Pade against the kernel's Taylor series with 13
    squarings: the stiffest idler mode makes ``||A dt|| ~ 5e3``), 2e-12 of Phi per step, so 1e-7 of the peak."""
    scene = load_network("fead_i4")
    run = simulate_slipping(None, scene, duration=0.05)
    assert run.events == () and not run.slip_state.any()
    lin = simulate_linear(scene, duration=0.05, method="exact", model="flexible")
    assert np.max(np.abs(run.speed - lin.speed)) <= 1e-7 * np.max(np.abs(lin.speed))
    assert np.max(np.abs(run.tension - lin.tension)) <= 1e-7 * np.max(np.abs(lin.tension))


def test_a_method_other_than_exact_is_refused_in_one_line():
    scene = square([{"type": "constant", "value": 1.0}, {"type": "constant", "value": 1.0}, {"type": "constant", "value": 0.0},
                    None], [1.0] * 4)
    with pytest.raises(SceneError, match="slipping tier steps the exact flow"):
        simulate_slipping(None, scene, method="rk4")


# ----------------------------------------------------------------------------- the kernel
def test_the_slip_kernel_compiles_once_whatever_the_scene():
    from belt_drive_ros.core.network import slip_kernel

    simulate_slipping(None, square([ramp(40.0), ramp(24.0), ramp(16.0), None], [0.25, 2, 2, 2], duration=0.05))
    first = len(slip_kernel.slip_steps.signatures)
    simulate_slipping(None, load_network("fead_i4"), duration=0.01)
    simulate_slipping(None, square([{"type": "constant", "value": 30.0}, {"type": "constant", "value": 6.0},
                                    {"type": "constant", "value": 6.0}, None], [2.0, 0.2, 0.2, 2.0], duration=0.05))
    assert first == 1 and len(slip_kernel.slip_steps.signatures) == 1


def test_the_slip_kernel_interpreted_gives_the_same_floats(tmp_path):
    """NUMBA_DISABLE_JIT=1 runs the slipping tier as Python: a run with onsets and re-sticks, bit for bit."""
    import os
    import subprocess
    import sys

    code = (
        "import sys, numpy as np\n"
        "sys.path.insert(0, sys.argv[2])\n"
        "from test_network_slip import square\n"
        "from belt_drive_ros.core.network.slip import simulate_slipping\n"
        "s = square([{'type': 'sine', 'mean': 0.0, 'amplitude': 30.0, 'frequency': 20.0}, {'type': 'constant', 'value': 6.0},"
        " {'type': 'constant', 'value': 6.0}, None], [2.0, 0.2, 0.2, 2.0], duration=0.06)\n"
        "r = simulate_slipping(None, s)\n"
        "np.save(sys.argv[1], np.hstack([r.states, r.slip_distance, r.slip_state, r.tension, [[len(r.events)]] * len(r.time)]))\n"
    )
    out = {}
    for jit in ("0", "1"):
        path = tmp_path / f"run_{jit}.npy"
        done = subprocess.run([sys.executable, "-c", code, str(path), os.path.dirname(__file__)],
                              env=dict(os.environ, NUMBA_DISABLE_JIT=jit), capture_output=True, text=True, timeout=900)
        assert done.returncode == 0, done.stderr[-2000:]
        out[jit] = np.load(path)
    assert out["0"][0, -1] >= 2, "the run must switch modes"
    assert np.array_equal(out["0"], out["1"])


def test_a_belt_sliding_on_every_pulley_is_a_one_line_error():
    """fead_i4 at 120 N installed tension, no bearing or arm damping, a pulsing alternator: every pulley reaches
    its limit; a massless belt then has no motion (the tension differences round the loop add up to zero, the
    limits do not)."""
    from belt_drive_ros.core.errors import SimulationDivergedError

    data = shipped("fead_i4")
    data["belt"]["installed_tension"] = 120.0
    data["tensioner"]["damping"] = 0.0
    for p in data["pulleys"]:
        p["damping"] = 0.0
        if p["name"] == "alternator":
            p["torque"] = {"type": "sine", "mean": 2.0, "amplitude": 3.0, "frequency": 40.0}
    scene = NetworkScene.from_mapping(data, "fead_loose")
    with pytest.raises(SimulationDivergedError, match=r"slides on every pulley at once at t = 0\.02\d+ s .*raise belt\.installed_tension"):
        simulate_slipping(None, scene, duration=0.1)


def test_auto_that_lands_on_the_slipping_tier_refuses_a_method_asked_for_by_name():
    """``auto`` finds the driver reaching its capstan limit; the slipping tier steps the exact flow only. A method
    asked for by name is refused in one line naming the pulley (it used to be replaced by exact silently); the
    scene's own method is replaced (run.method says exact); exact by name runs."""
    scene = dataclasses.replace(square([ramp(40.0, 0.2), ramp(24.0, 0.2), ramp(16.0, 0.2), None], [0.25, 2, 2, 2],
                                       duration=0.3), method="etd2")
    for method in ("rk4", "etd2", "trapezoidal"):
        with pytest.raises(SceneError) as refused:
            simulate_linear(scene, method=method)
        text = str(refused.value)
        assert "\n" not in text and text.startswith(f"method {method}: the run slips (driver reaches the capstan limit")
        assert "exact flow of each stick/slip mode only" in text
    run = simulate_linear(scene)
    assert run.tier == "slipping" and run.method == "exact"
    assert run.reason.startswith("slipping: driver reaches the capstan limit")
    named = simulate_linear(scene, method="exact")
    assert named.tier == "slipping" and np.array_equal(named.states, run.states)


def test_belt_drive_sim_refuses_a_method_the_slipping_run_cannot_step(tmp_path, capsys):
    """From the command line: ``--method rk4`` on a run that slips exits 2 with one line; without --method the
    scene's method steps the linear tier's probe and the slipping run is exact."""
    import yaml

    from belt_drive_ros.cli import main

    torques = [ramp(40.0, 0.2), ramp(24.0, 0.2), ramp(16.0, 0.2), None]
    raw = {"kind": "network", "name": "greasy", "duration": 0.3, "dt": 1e-3, "initial_speed": 0.0, "method": "etd2",
           "belt": {"EA": 2.0e4, "damping": 2.0, "installed_tension": 300.0},
           "pulleys": _square_pulleys(torques, [0.25, 2, 2, 2])}
    path = tmp_path / "greasy.yaml"
    path.write_text(yaml.safe_dump(raw))
    assert main(["sim", str(path), "--method", "rk4"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "method rk4: the run slips (driver reaches the capstan limit" in err
    assert main(["sim", str(path)]) == 0
    first = capsys.readouterr().out.splitlines()[0]
    assert "slipping tier, exact at dt = 0.001 s" in first
    # the process's first run: its wall time holds the kernels' loading, and the line says so (it read as the speed)
    assert "x real time, loading the compiled kernels included" in first


def test_the_slipping_tier_splits_a_step_at_a_breakpoint_inside_it():
    """A load step at 12.5 ms inside the 1 ms grid's step 12: the step is split there (each piece the exact flow
    with the torques held from its start), so the run equals one on a 0.5 ms grid at the common times, while
    sticking (to the exponentials' rounding, as the linear tier's exact run) and through an onset of slip."""
    torques = [{"type": "constant", "value": 1.0},
               {"type": "step", "initial": 0.5, "final": 3.0, "time": 0.0125},
               {"type": "constant", "value": 0.5}, None]
    for mus, slips in (([2.0] * 4, False), ([2.0, 0.05, 2.0, 2.0], True)):
        scene = square(torques, mus, duration=0.05)
        coarse = simulate_slipping(None, scene)
        fine = simulate_slipping(None, scene, dt=5e-4)
        assert bool(coarse.events) == slips and len(coarse.events) == len(fine.events)
        for a, b in zip(coarse.events, fine.events):
            assert (a.pulley, a.kind) == (b.pulley, b.kind) and abs(a.time - b.time) <= 1e-9
        assert np.max(np.abs(coarse.tension - fine.tension[::2])) <= 1e-7 * np.max(np.abs(fine.tension))
        assert np.max(np.abs(coarse.speed - fine.speed[::2])) <= 1e-7 * np.max(np.abs(fine.speed))


def test_the_slipping_tiers_csv_has_each_pulleys_slip_and_slip_speed(tmp_path):
    """As the MCAP has P/slip and P/slip_speed, the CSV of a slipping-tier run has those columns (a linear tier's none)."""
    from belt_drive_ros.cli import main
    from belt_drive_ros.core.network.simulate import simulate

    import yaml

    data = parse_yaml((resources.files("belt_drive_ros") / "scenes" / "networks" / "paper_network.yaml").read_text(), "x")
    data["belt"]["installed_tension"] = 100.0  # the paper drive at a low tension: it slips (as above)
    for p in data["pulleys"]:
        p["mu"] = 0.5
    scene_file = tmp_path / "paper_slip.yaml"
    scene_file.write_text(yaml.safe_dump(data))
    out = tmp_path / "run.csv"
    assert main(["sim", str(scene_file), "--quiet", "--model", "slipping", "--duration", "1.0", "--out", str(out)]) == 0
    table = np.genfromtxt(out, delimiter=",", names=True, deletechars="")
    scene = NetworkScene.from_mapping(data, "paper_slip")
    run = simulate(scene, duration=1.0, model="slipping")
    for i, p in enumerate(scene.pulleys):
        np.testing.assert_array_equal(table[f"{p.name}/slip"], run.slip[:, i])
        np.testing.assert_array_equal(table[f"{p.name}/slip_speed"], run.slip_speed[:, i])
    assert run.slip.any() and np.abs(run.slip_speed).max() > 0.0
    linear = tmp_path / "linear.csv"
    assert main(["sim", str(scene_file), "--quiet", "--model", "flexible", "--duration", "0.2", "--out", str(linear)]) == 0
    assert "slip_speed" not in linear.read_text().splitlines()[0]
