"""Belt networks (first tier): geometry, statics, arm stiffness, modes, energy, the paper's drive as a network.

Every reference here is computed in the test from the geometry and the
equations written out by hand (docs/serpentine.md), not by the package's
network code.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from belt_drive_ros.core.errors import SceneError
from belt_drive_ros.core.network.model import NetworkModel, undamped_frequencies
from belt_drive_ros.core.network.simulate import simulate
from belt_drive_ros.core.network.scene import NetworkScene
from belt_drive_ros.io.scenes import load_network


def _pulley(name, centre, radius, role="idler", side="inner", inertia=1e-3, torque=None, damping=0.0):
    p = {"name": name, "centre": list(centre), "radius": radius, "inertia": inertia, "role": role,
         "side": side, "damping": damping}
    if torque is not None:
        p["torque"] = torque
    return p


def _scene(pulleys, tensioner=None, T0=300.0, EA=1.0e5, damping=0.0, **extra):
    data = {"kind": "network", "pulleys": pulleys, "duration": 0.1, "dt": 1e-4, "initial_speed": 0.0,
            "belt": {"EA": EA, "damping": damping, "mass_per_length": 0.0}}
    if tensioner is None:
        data["belt"]["installed_tension"] = T0
    else:
        data["tensioner"] = tensioner
        if "preload" not in tensioner:
            data["belt"]["installed_tension"] = T0
    data.update(extra)
    return NetworkScene.from_mapping(data)


# ---------------------------------------------------------------------- hand geometry of the test
def _span(c0, rho0, c1, rho1):
    """Tangent from circle 0 to circle 1 (signed radii; belt on the left of travel for rho > 0), by the tangent
    points: a unit normal u with u . (c1 - c0) = rho1 - rho0 ... solved here as a 2x2 rotation, independently:
    the direction e makes angle gamma with the centre line, sin(gamma) = (rho0 - rho1) / D."""
    d = np.subtract(c1, c0)
    D = math.hypot(*d)
    gamma = math.asin((rho0 - rho1) / D)
    cg, sg = math.cos(gamma), math.sin(gamma)
    e = np.array([cg * d[0] - sg * d[1], sg * d[0] + cg * d[1]]) / D
    a = np.asarray(c0) - rho0 * np.array([-e[1], e[0]])
    b = np.asarray(c1) - rho1 * np.array([-e[1], e[0]])
    return e, a, b


def _belt_length(centres, radii, sides):
    """Sum of tangent lengths (|b - a|) plus arcs; wraps as turning angles of the tangent directions."""
    n = len(centres)
    rho = [s * r for s, r in zip(sides, radii)]
    spans = [_span(centres[j], rho[j], centres[(j + 1) % n], rho[(j + 1) % n]) for j in range(n)]
    total = sum(math.hypot(*(b - a)) for _, a, b in spans)
    for i in range(n):
        e0, e1 = spans[i - 1][0], spans[i][0]
        turn = math.atan2(e0[0] * e1[1] - e0[1] * e1[0], e0 @ e1)  # (-pi, pi]
        wrap = (sides[i] * turn) % (2 * math.pi)
        total += radii[i] * wrap
    return total


# ---------------------------------------------------------------------- geometry
def test_rectangle_of_four_equal_pulleys():
    a, b, r = 0.4, 0.25, 0.05
    scene = _scene([_pulley("p0", (0, 0), r, "driver", torque=0.0), _pulley("p1", (a, 0), r),
                    _pulley("p2", (a, b), r), _pulley("p3", (0, b), r)])
    g = scene.geometry
    np.testing.assert_allclose(g.lengths, [a, b, a, b], rtol=1e-14)
    np.testing.assert_allclose(g.wraps, [math.pi / 2] * 4, rtol=1e-14)
    assert g.belt_length == pytest.approx(2 * a + 2 * b + 2 * math.pi * r, rel=1e-14)
    np.testing.assert_allclose(g.directions, [[1, 0], [0, 1], [-1, 0], [0, -1]], atol=1e-15)


def test_backside_idler_dents_the_span():
    d, r, ri, h = 0.4, 0.05, 0.03, 0.07
    scene = _scene([_pulley("left", (0, 0), r, "driver", torque=0.0), _pulley("right", (d, 0), r),
                    _pulley("idler", (d / 2, h), ri, side="backside")])
    g = scene.geometry
    D = math.hypot(d / 2, h)
    L = math.sqrt(D * D - (r + ri) ** 2)  # internal tangent, by Pythagoras
    alpha = math.asin((r + ri) / D) - math.atan2(h, d / 2)  # how far the belt slopes down into the idler
    assert alpha > 0
    np.testing.assert_allclose(g.lengths, [d, L, L], rtol=1e-13)
    np.testing.assert_allclose(g.wraps, [math.pi + alpha, math.pi + alpha, 2 * alpha], rtol=1e-12)
    assert g.belt_length == pytest.approx(d + 2 * L + 2 * r * (math.pi + alpha) + 2 * ri * alpha, rel=1e-13)


@pytest.mark.parametrize("pulleys, named", [
    ([_pulley("a", (0, 0), 0.05, "driver", torque=0.0), _pulley("b", (0.08, 0), 0.05)], "pulleys.b: overlaps pulley a"),
    ([_pulley("l", (0, 0), 0.05, "driver", torque=0.0), _pulley("r", (0.4, 0), 0.05),
      _pulley("idler", (0.2, 0.2), 0.03, side="backside")], "pulleys.idler: wrap angle <= 0"),
    ([_pulley("a", (0, 0), 0.05, "driver", torque=0.0), _pulley("b", (0.4, 0), 0.05),  # a figure eight
      _pulley("c", (0, 0.3), 0.05), _pulley("d", (0.4, 0.3), 0.05)], "pulleys.c: wrap angle <= 0"),
    ([_pulley("a", (0, 0), 0.05, "driver", torque=0.0), _pulley("b", (0.4, 0), 0.05),  # inside the loop
      _pulley("c", (0.2, 0.3), 0.05), _pulley("mid", (0.2, 0.02), 0.04)], "pulleys.mid: wrap angle <= 0"),
    ([_pulley("a", (0, 0), 0.05, "driver", torque=0.0), _pulley("b", (0.4, 0), 0.05),
      _pulley("c", (0.2, 0.35), 0.05), _pulley("d", (0.2, -0.03), 0.03, side="backside")],
     "pulleys.d: the span a -> b crosses it"),
    ([_pulley("a", (0, 0), 0.05, "driver", torque=0.0), _pulley("b", (0.4, 0), 0.05),
      _pulley("c", (0.2, 0.3), 0.05), _pulley("far", (0.2, -0.3), 0.04, side="backside")],
     "pulleys.b: not a simple loop: the span a -> b crosses the span c -> far"),
])
def test_bad_layouts_are_one_line_errors_naming_the_pulley(pulleys, named):
    with pytest.raises(SceneError) as info:
        _scene(pulleys)
    text = str(info.value)
    assert named in text and "\n" not in text


# ---------------------------------------------------------------------- a drive with a tensioner
CRANK = {"type": "constant", "value": 0.0}


def _tensioned(damping=0.0, loads=(2.0, 1.0), bearing=0.0):
    """Crank, alternator, A/C and a backside tensioner on the crank's slack side (leaving the crank)."""
    return _scene([
        _pulley("crank", (0, 0), 0.08, "driver", inertia=0.2, torque=CRANK, damping=bearing),
        _pulley("tens", (0.13, 0.05), 0.035, "tensioner", side="backside", inertia=1e-4, damping=bearing),
        _pulley("alt", (0.26, 0.15), 0.03, "accessory", inertia=3e-3, torque={"type": "constant", "value": loads[0]},
                damping=bearing),
        _pulley("ac", (-0.12, 0.22), 0.06, "accessory", inertia=2e-3, torque={"type": "constant", "value": loads[1]},
                damping=bearing),
    ], tensioner={"pivot": [0.17, -0.01], "inertia": 1.5e-3, "spring_rate": 25.0, "damping": damping},
        T0=300.0, EA=1.2e5, damping=damping)


def _arm_lambda(scene, theta):
    """Exact belt length with the tensioner's arm at ``theta`` (the test's own geometry)."""
    t = scene.index(scene.tensioner.pulley)
    piv = np.asarray(scene.tensioner.pivot)
    c_t = np.asarray(scene.pulleys[t].centre)
    La = math.hypot(*(c_t - piv))
    centres = [np.asarray(p.centre, dtype=float) for p in scene.pulleys]
    centres[t] = piv + La * np.array([math.cos(theta), math.sin(theta)])
    return _belt_length(centres, [p.radius for p in scene.pulleys], [p.side for p in scene.pulleys])


def _arm_angle(scene):
    t = scene.index(scene.tensioner.pulley)
    c = np.subtract(scene.pulleys[t].centre, scene.tensioner.pivot)
    return math.atan2(c[1], c[0])


def _derivatives(f, x, h):
    return (f(x + h) - f(x - h)) / (2 * h), (f(x + h) - 2 * f(x) + f(x - h)) / (h * h)


def test_arm_preload_and_stiffness_against_finite_differences_of_the_exact_geometry():
    scene = _tensioned()
    model = NetworkModel.build(scene)
    th0 = _arm_angle(scene)
    d1, d2 = _derivatives(lambda th: _arm_lambda(scene, th), th0, 1e-4)
    T0 = scene.belt.installed_tension
    # the spring preload holds the arm against a uniform T0: P = T0 dLambda/dtheta
    assert scene.tensioner.preload == pytest.approx(T0 * d1, rel=1e-6)
    # the arm's geometric stiffness at T0: T0 d2Lambda/dtheta2 (a few per cent of the spring: not negligible)
    k_geo = model.geometric_stiffness(np.full(4, T0))
    assert k_geo == pytest.approx(T0 * d2, rel=1e-5)
    assert abs(k_geo) > 0.01 * scene.tensioner.spring_rate


def test_static_tensions_and_arm_equilibrium_under_constant_loads():
    scene = _tensioned(loads=(2.5, 1.2))
    model = NetworkModel.build(scene)
    q, T, Q = model.static([0.0, 0.0, -2.5, -1.2])
    r = [p.radius for p in scene.pulleys]
    # each pulley: r_i (T_i - T_{i-1}) = -Q_i  (the span leaving minus the span arriving)
    for i in range(4):
        assert r[i] * (T[i] - T[i - 1]) == pytest.approx(-Q[i], abs=1e-9 * 300)
    assert Q[0] == pytest.approx(r[0] * (2.5 / r[2] + 1.2 / r[3]), rel=1e-14)  # the crank carries both
    assert T[3] > T[0]  # the span arriving at the driver is the tight one
    assert T[0] == pytest.approx(T[1], rel=1e-12)  # the tensioner (no torque) passes its tension on
    # the arm: spring (preload - k_a dtheta) against the belt's pull T_t dLambda/dtheta at the displaced angle,
    # to first order in dtheta (the linear tier)
    th0, dth = _arm_angle(scene), q[-1]
    d1, d2 = _derivatives(lambda th: _arm_lambda(scene, th), th0, 1e-4)
    spring = scene.tensioner.preload - scene.tensioner.spring_rate * dth
    assert spring == pytest.approx(T[0] * (d1 + d2 * dth), rel=1e-6)
    assert dth != 0.0


def test_natural_frequencies_against_an_eigen_analysis_from_the_equations():
    scene = _tensioned()
    P = scene.pulleys
    r = np.array([p.radius for p in P])
    n = len(P)
    th0 = _arm_angle(scene)
    t = scene.index(scene.tensioner.pulley)
    La = math.hypot(*np.subtract(P[t].centre, scene.tensioner.pivot))
    n_a = La * np.array([-math.sin(th0), math.cos(th0)])  # d c_t / d theta_a
    rho = [p.side * p.radius for p in P]
    a = np.zeros((n, n + 1))
    lengths = []
    for j in range(n):
        k = (j + 1) % n
        e, pa, pb = _span(P[j].centre, rho[j], P[k].centre, rho[k])
        lengths.append(math.hypot(*(pb - pa)))
        a[j, k] += r[k]
        a[j, j] -= r[j]
        a[j, n] = (n_a @ e) * ((k == t) - (j == t))  # (u_{j+1} - u_j) . e_j per unit arm angle
    kj = scene.belt.EA / np.array(lengths)
    K = a.T @ np.diag(kj) @ a
    _, d2 = _derivatives(lambda th: _arm_lambda(scene, th), th0, 1e-4)
    K[n, n] += scene.tensioner.spring_rate + scene.belt.installed_tension * d2
    M = np.diag([p.inertia for p in P] + [scene.tensioner.inertia])
    w2 = np.sort(np.linalg.eigvals(np.linalg.solve(M, K)).real)
    assert abs(w2[0]) < 1e-6 * w2[-1]  # the belt turning every pulley: no stretch
    expected = np.sqrt(w2[1:]) / (2 * math.pi)
    np.testing.assert_allclose(undamped_frequencies(NetworkModel.build(scene)), expected, rtol=1e-6)


def test_energy_balance_on_an_undamped_run():
    scene = NetworkScene.from_mapping({**_raw_tensioned(), "method": "exact", "initial_speed": 60.0,
                                       "duration": 0.2, "dt": 1e-4})
    run = simulate(scene, model="flexible")
    P = scene.pulleys
    J = np.array([p.inertia for p in P])
    kinetic = 0.5 * (run.speed**2 @ J) + 0.5 * scene.tensioner.inertia * run.states[:, -1] ** 2
    lengths = scene.geometry.lengths
    T0 = scene.belt.installed_tension
    strain = (run.tension - T0) ** 2 @ (lengths / scene.belt.EA) / 2.0  # sum (T - T0)^2 / (2 k_j)
    th0 = _arm_angle(scene)
    dth = run.arm_angle - th0
    _, d2 = _derivatives(lambda th: _arm_lambda(scene, th), th0, 1e-4)
    arm = 0.5 * (scene.tensioner.spring_rate + T0 * d2) * dth**2
    work = (run.angle - run.angle[0]) @ np.array([3.0, 0.0, -2.0, -1.0])  # the crank's drive, the loads on alt and ac
    E = kinetic + strain + arm - work
    assert np.ptp(E) <= 1e-9 * np.ptp(kinetic)  # 3e-11 measured (method exact, constant torques)
    assert np.ptp(strain) > 1e-2  # the belt did ring (0.032 J)


def _raw_tensioned():
    return {"kind": "network", "belt": {"EA": 1.2e5, "damping": 0.0, "mass_per_length": 0.0, "installed_tension": 300.0},
            "tensioner": {"pivot": [0.17, -0.01], "inertia": 1.5e-3, "spring_rate": 25.0, "damping": 0.0},
            "pulleys": [
                _pulley("crank", (0, 0), 0.08, "driver", inertia=0.2, torque={"type": "constant", "value": 3.0}),
                _pulley("tens", (0.13, 0.05), 0.035, "tensioner", side="backside", inertia=1e-4),
                _pulley("alt", (0.26, 0.15), 0.03, "accessory", inertia=3e-3, torque={"type": "constant", "value": 2.0}),
                _pulley("ac", (-0.12, 0.22), 0.06, "accessory", inertia=2e-3, torque={"type": "constant", "value": 1.0}),
            ]}


# ---------------------------------------------------------------------- the paper's drive as a network
def test_paper_drive_as_a_two_pulley_network_equals_the_flexible_model():
    from belt_drive_ros.io.scenes import load_scene
    from belt_drive_ros.core.simulate import simulate as simulate_paper

    paper = load_scene("paper")
    today = simulate_paper(paper, model="flexible", method="etd2", dt=1e-3)
    net = simulate(load_network("paper_network"), model="flexible")
    g = paper.params.gear_ratio
    np.testing.assert_array_equal(net.time, today.time)
    for ours, theirs in ((net.speed[:, 1], today["omega_3"]), (net.speed[:, 0], g * today["omega_M"]),
                         (net.belt_torque[:, 1], today["belt_torque"])):
        assert np.max(np.abs(ours - theirs)) <= 1e-10 * np.max(np.abs(theirs))  # 3e-12 (speeds), 2e-11 measured
    assert not net.slack.any()


# ---------------------------------------------------------------------- the commands
def test_scenes_prints_a_networks_geometry(capsys):
    from belt_drive_ros.cli import main

    assert main(["scenes", "fead_i4"]) == 0
    out = capsys.readouterr().out
    scene = load_network("fead_i4")
    for p in scene.pulleys:
        assert p.name in out
    assert f"belt length {scene.geometry.belt_length:.4f} m" in out
    assert main(["scenes"]) == 0
    assert "fead_i4" in capsys.readouterr().out


def test_modes_and_campbell(tmp_path, capsys):
    from belt_drive_ros.cli import main

    png = tmp_path / "campbell.png"
    assert main(["modes", "fead_i4", "--campbell", str(png), "--points", "12"]) == 0
    out = capsys.readouterr().out
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    scene = load_network("fead_i4")
    rows = [line.split() for line in out.splitlines() if line[:4].strip().isdigit()]
    undamped = undamped_frequencies(NetworkModel.build(scene))
    assert len(rows) >= 5
    # the printed undamped frequencies of the stiff modes sit near the bare K-M ones (operating tensions differ a bit)
    assert float(rows[-1][2]) == pytest.approx(undamped[-1], rel=0.02)
    assert "crossing: mode" in out and "order 2" in out
    assert main(["modes", "fead_i4", "--campbell", str(png)]) == 2  # exists: --force
    assert main(["modes", "paper"]) == 2  # not a network scene
    err = capsys.readouterr().err
    assert err.count("\n") == 2 and "unknown network scene 'paper'" in err


def test_a_bad_network_file_is_one_error_line(tmp_path, capsys):
    from belt_drive_ros.cli import main

    bad = tmp_path / "bad.yaml"
    bad.write_text("kind: network\nduration: 1\ndt: 0.001\ninitial_speed: 0\n"
                   "belt: {EA: 1.0e5, damping: 0, installed_tension: 200}\n"
                   "pulleys:\n  - {name: crank, role: driver, centre: [0, 0], radius: 0.08, inertia: 0.2, torque: 1.0}\n"
                   "  - {name: alt, role: accessory, centre: [0.1, 0], radius: 0.03, inertia: 0.003, torque: 1.0}\n")
    assert main(["scenes", str(bad)]) == 2
    err = capsys.readouterr().err
    assert err == "belt-drive: error: pulleys.alt: overlaps pulley crank (centres 0.1 m apart, radii 0.08 + 0.03 m)\n"


def test_sim_runs_a_network_and_writes_its_csv_by_pulley_and_span(tmp_path, capsys):
    from belt_drive_ros.cli import main

    out = tmp_path / "fead.csv"
    assert main(["sim", "fead_i4", "--duration", "0.02", "--out", str(out)]) == 0
    scene = load_network("fead_i4")
    names = out.read_text().splitlines()[0].split(",")
    table = np.loadtxt(out, delimiter=",", skiprows=1)
    run = simulate(scene, duration=0.02)
    assert table.shape == (21, len(names))
    np.testing.assert_array_equal(table[:, names.index("alternator/speed")], run.speed[:, scene.index("alternator")])
    np.testing.assert_array_equal(table[:, names.index("spans/ac_compressor_crank/tension")], run.tension[:, -1])
    np.testing.assert_array_equal(table[:, names.index("tensioner_arm/angle")], run.arm_angle)
    assert "tensioner arm:" in capsys.readouterr().out
    assert main(["sim", "fead_i4", "--out", str(tmp_path / "x.txt")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "writes .csv or .mcap" in err
    png = tmp_path / "run.png"
    assert main(["sim", "fead_i4", "--duration", "0.01", "--plot", str(png)]) == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize("change, message", [
    (lambda d: d["pulleys"][1].update(name=["x"]), "pulleys.[1].name: letters"),
    (lambda d: d["pulleys"][1].update(side=["inner"]), "pulleys.tens.side: must be inner or backside"),
    (lambda d: d["pulleys"][2].update(role={"a": 1}), "pulleys.alt.role: must be one of"),
    (lambda d: d["pulleys"][2].update(centre=["0", 1]), "pulleys.alt.centre[0]: must be a number"),
    (lambda d: d["pulleys"][2].update(radius=-0.03), "pulleys.alt.radius: must be >= 0.0001"),
    (lambda d: d["pulleys"][2].update(radius=1e-300), "pulleys.alt.radius: must be >= 0.0001, got 1e-300"),
    (lambda d: d["pulleys"][2].pop("torque"), "pulleys.alt.torque: missing"),
    (lambda d: d["pulleys"][1].update(torque=1.0), "pulleys.tens.torque: a tensioner carries no torque"),
    (lambda d: d["pulleys"].append("x"), "pulleys.[4]: expected a mapping"),
    (lambda d: d.pop("tensioner"), "tensioner: missing (pulley tens has role tensioner)"),
    (lambda d: d["tensioner"].update(preload=5.0), "belt.installed_tension: give either it or tensioner.preload"),
    (lambda d: d["belt"].update(EA="1e5"), "belt.EA: must be a number"),
    (lambda d: d.update(method="nope"), "method:"),
    (lambda d: d.update(engine=[4]), "engine: expected a mapping"),
    (lambda d: d.update(pulleys={"a": 1}), "pulleys: expected a list"),
])
def test_bad_network_values_are_one_line_errors(change, message):
    data = _raw_tensioned()
    data.update(duration=0.1, dt=1e-4, initial_speed=0.0)
    change(data)
    with pytest.raises(SceneError) as info:
        NetworkScene.from_mapping(data)
    assert message in str(info.value) and "\n" not in str(info.value)


def test_preload_gives_the_installed_tension():
    data = _raw_tensioned()
    data.update(duration=0.1, dt=1e-4, initial_speed=0.0)
    base = NetworkScene.from_mapping(data)
    del data["belt"]["installed_tension"]
    data["tensioner"]["preload"] = base.tensioner.preload
    again = NetworkScene.from_mapping(data)
    assert again.belt.installed_tension == pytest.approx(300.0, rel=1e-12)


def test_hub_loads_and_slack_flags_of_a_rectangle():
    a, b, r, T0, m = 0.4, 0.25, 0.05, 300.0, 0.1
    data = {"kind": "network", "duration": 0.01, "dt": 1e-4, "initial_speed": 0.0, "method": "exact",
            "belt": {"EA": 1.0e5, "damping": 0.0, "mass_per_length": m, "installed_tension": T0},
            "pulleys": [_pulley("p0", (0, 0), r, "driver", torque=0.0), _pulley("p1", (a, 0), r),
                        _pulley("p2", (a, b), r), _pulley("p3", (0, b), r)]}
    run = simulate(NetworkScene.from_mapping(data))
    np.testing.assert_allclose(run.tension, T0, rtol=1e-12)  # nothing loads the belt: it stays at T_0
    np.testing.assert_allclose(run.hub_load, T0 * math.sqrt(2.0), rtol=1e-12)  # two spans at right angles
    assert not run.slack.any()
    v = 1.01 * math.sqrt(T0 / m)  # belt speed past which the centrifugal tension m' v^2 exceeds T_0
    run = simulate(NetworkScene.from_mapping({**data, "initial_speed": v / r}))
    assert run.slack.all()
    run = simulate(NetworkScene.from_mapping({**data, "initial_speed": 0.99 * v / r}))
    assert not run.slack.any()


def test_campbell_crossings_lie_on_both_lines():
    from belt_drive_ros.core.network.campbell import campbell

    data = campbell(NetworkModel.build(load_network("fead_i4")), points=15)
    assert data.orders == (2.0, 4.0, 6.0)
    assert len(data.crossings) >= 3
    for c in data.crossings:
        assert c.frequency == pytest.approx(c.order * c.speed / (2 * math.pi), rel=1e-12)
        assert c.frequency == pytest.approx(np.interp(c.speed, data.speeds, data.frequencies[:, c.mode - 1]), rel=1e-9)


def test_an_unstable_step_is_refused_before_the_run():
    from belt_drive_ros.core.errors import UnstableStepError

    scene = load_network("fead_i4")
    with pytest.raises(UnstableStepError, match=r"method rk4 at dt = 0.001 s grows the 97[0-9.]* Hz mode.*dt <= 0.000468 s is stable"):
        simulate(scene, duration=0.01, dt=1e-3, method="rk4", model="flexible")
    run = simulate(scene, duration=0.01, dt=4.6e-4, method="rk4", model="flexible")  # the step it names runs, bounded
    assert np.all(np.isfinite(run.states)) and np.max(np.abs(run.speed)) < 300.0


def test_serpentine_doc_quotes_the_unstable_step_refusal_as_it_reads():
    """docs/serpentine.md quotes this refusal; its stable step said 0.00025 s where the guard names 0.000468 s."""
    import re
    from pathlib import Path

    from belt_drive_ros.core.errors import UnstableStepError

    doc = " ".join((Path(__file__).resolve().parents[1] / "docs" / "serpentine.md").read_text(encoding="utf-8").split())
    head, _, tail = re.search(r"`(method rk4 at dt = 0\.001 s grows the [^`]*)`", doc).group(1).partition("...")
    with pytest.raises(UnstableStepError) as refused:
        simulate(load_network("fead_i4"), duration=0.01, dt=1e-3, method="rk4", model="flexible")
    message = str(refused.value)
    assert message.startswith(head.strip()) and message.endswith(tail.strip()), (message, head, tail)


def test_the_tensioner_side_flips_when_the_bsg_drives():
    """Crank driving: the tensioner's spans are the slack ones; the BSG cranking the engine: the tight ones."""
    for name, tight in (("fead_i4", False), ("bsg_start_network", True)):
        scene = load_network(name)
        model = NetworkModel.build(scene)
        q, T, _ = model.static(model.operating_loads(scene.operating_speed))
        t = scene.index(scene.tensioner.pulley)
        at_arm = [T[t - 1], T[t]]  # arriving at and leaving the tensioner
        others = np.delete(T, [(t - 1) % len(T), t])
        assert (min(at_arm) > max(others)) if tight else (max(at_arm) < min(others))
        assert (q[-1] < 0) if tight else (q[-1] > 0)  # the arm pushed back / let out


def test_a_damped_run_under_balanced_constant_torques_settles_on_the_static_tensions():
    data = _raw_tensioned()
    r = {p["name"]: p["radius"] for p in data["pulleys"]}
    drive = r["crank"] * (2.0 / r["alt"] + 1.0 / r["ac"])  # balances the loads: sum Q_i / r_i = 0
    data["pulleys"][0]["torque"] = {"type": "constant", "value": drive}
    data["belt"]["damping"] = 2.0
    data["tensioner"]["damping"] = 0.5
    data.update(duration=1.0, dt=1e-4, initial_speed=50.0, method="etd2")
    scene = NetworkScene.from_mapping(data)
    run = simulate(scene, model="flexible")
    model = NetworkModel.build(scene)
    q, T, _ = model.static([drive, 0.0, -2.0, -1.0], iterations=1)  # the run's linearisation: k_geo at T_0
    np.testing.assert_allclose(run.tension[-1], T, rtol=1e-6)
    assert run.arm_angle[-1] - _arm_angle(scene) == pytest.approx(q[-1], rel=1e-5)
    _, T_op, _ = model.static([drive, 0.0, -2.0, -1.0])  # k_geo at the static tensions: a second-order shift
    assert 0.0 < np.max(np.abs(T_op - T)) < 2e-3 * np.max(T)  # 0.52 N of 368 N measured
    np.testing.assert_allclose(run.speed[-1] * [p.radius for p in scene.pulleys], 50.0 * 0.08, rtol=1e-6)


def test_friction_use_against_the_capstan_closed_form():
    """Two pulleys, one load: T_tight + T_slack = 2 T_0, so friction use = (Q / r) / (2 T_0 tanh(mu beta / 2))."""
    from belt_drive_ros.core.network.model import outputs

    def friction_use(scene, T, v):  # a run's friction use: span tensions T [N], the belt at v [m/s]
        model = NetworkModel.build(scene)
        m, d = model.M.shape[0], scene.driver
        states = np.zeros((1, 2 * m))
        states[0, m + d] = v / scene.pulleys[d].radius
        return outputs(model, np.zeros(1), states, np.asarray(T, dtype=float)[None, :]).friction_use[0]

    scene = load_network("paper_network")
    model = NetworkModel.build(scene)
    Q, r3, T0 = 3.0, 0.05, scene.belt.installed_tension
    _, T, _ = model.static([0.0, -Q])
    assert T[0] + T[1] == pytest.approx(2 * T0, rel=1e-12)
    D, dr = 0.30016662039607267, 0.01
    beta3 = math.pi - 2 * math.asin(dr / D)  # the smaller pulley's wrap
    mu = scene.pulleys[1].mu
    use = friction_use(scene, T, 0.0)
    assert use[1] == pytest.approx(Q / r3 / (2 * T0 * math.tanh(mu * beta3 / 2)), rel=1e-12)
    v = 20.0  # with the centrifugal tension m' v^2 taken off both spans
    heavy = NetworkScene.from_mapping({**_paper_network_raw(), "belt": {**_paper_network_raw()["belt"],
                                                                          "mass_per_length": 0.2}})
    assert friction_use(heavy, T, v)[1] == pytest.approx(Q / r3 / (2 * (T0 - 0.2 * v * v) * math.tanh(mu * beta3 / 2)),
                                                          rel=1e-12)


def _paper_network_raw():
    from importlib import resources

    import yaml

    text = (resources.files("belt_drive_ros") / "scenes" / "networks" / "paper_network.yaml").read_text()
    return yaml.safe_load(text)


def test_sim_names_the_first_pulley_at_its_capstan_limit(tmp_path, capsys):
    from belt_drive_ros.cli import main

    raw = _paper_network_raw()
    raw["pulleys"][1]["mu"] = 0.02  # a greasy pulley 3: the run-up's torque passes its limit
    path = tmp_path / "greasy.yaml"
    import yaml

    path.write_text(yaml.safe_dump(raw))
    assert main(["sim", str(path), "--duration", "0.5", "--model", "flexible"]) == 0
    out = capsys.readouterr().out
    assert "capstan limit: pulley_3 reaches it first at t = " in out and "not valid" in out


def test_a_network_recording_names_each_joint_states_field_unit(tmp_path, capsys):
    """The units record gives joint_states' position, velocity and effort a unit each (as a drive recording's):
    one string "rad, rad/s, N*m" for the topic labelled every exported column with all three."""
    from belt_drive_ros.cli import main
    from msg_tools.cli import main as msg_tools

    out = tmp_path / "fead.mcap"
    assert main(["sim", "fead_i4", "--duration", "0.01", "--out", str(out)]) == 0
    capsys.readouterr()
    assert msg_tools(["export", str(out), "-t", "/joint_states"]) == 0
    header = capsys.readouterr().out.splitlines()[0].split(",")
    assert "position[crank] [rad]" in header and "velocity[crank] [rad/s]" in header
    assert "effort[crank] [N*m]" in header and "position[tensioner_arm] [rad]" in header
    assert not any("rad, rad/s" in column for column in header)


def test_a_tensioner_arm_unstable_at_its_installed_angle_is_refused_naming_the_spring(tmp_path, capsys):
    """fead_i4 with a soft belt (EA 2e3 N) and spring (0.5 N m/rad): the installed stiffness has a negative
    eigenvalue (the geometric stiffness wins), the flexible tier a real eigenvalue of +16.5 1/s. scenes and modes
    printed it as normal and sim blamed the step ("exact at dt = 0.001 s grows the 126.1 Hz mode: use exact ...")."""
    import yaml

    from belt_drive_ros.cli import main
    from belt_drive_ros.io.scenes import _shipped_text, load_network

    data = yaml.safe_load(_shipped_text("fead_i4", "networks"))
    data["belt"]["EA"], data["tensioner"]["spring_rate"] = 2.0e3, 0.5
    path = tmp_path / "soft.yaml"
    path.write_text(yaml.safe_dump(data))
    for argv in (["sim", str(path)], ["modes", str(path)]):
        assert main(argv) == 2
        assert capsys.readouterr().err.startswith("belt-drive: error: tensioner.spring_rate: the arm is unstable at "
                                                  "its installed angle")
    data["tensioner"]["spring_rate"] = 50.0  # held
    path.write_text(yaml.safe_dump(data))
    assert main(["modes", str(path)]) == 0
    load_network("fead_i4")  # (the shipped scenes: stable)


def test_network_scene_edges_named_and_a_network_file_by_any_name(tmp_path, capsys):
    """A network file named .YAML (or without .yaml) was taken for a drive scene and told to use the command just
    run; a scene name that is a mapping printed as the name; a pulley centre at 1e8 m ran (a 2e8 m belt); a run-up of
    6e7 steps allocated ~8 GB where sim refuses past 5e6 samples; the excitation of a 4-cylinder's 2nd firing
    harmonic was 'firing order 2' (it is engine order 4)."""
    import yaml

    from belt_drive_ros.cli import main
    from belt_drive_ros.io.scenes import _shipped_text, is_network

    text = _shipped_text("fead_i4", "networks")
    for name in ("net.YAML", "net"):
        (tmp_path / name).write_text(text)
        assert is_network(tmp_path / name)
    assert main(["sim", str(tmp_path / "net.YAML"), "--duration", "0.01", "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "engine order 4 reaches" in out
    for change, message in ((lambda d: d.update(name={"a": 1}), "name: expected text, got dict"),
                            (lambda d: d["pulleys"][2].update(centre=[1e8, 0.1]),
                             "pulleys.alternator.centre[0]: 1e+08 is outside the plausible range (up to 1000)"),
                            (lambda d: d.update(dt=1e-5), None)):
        data = yaml.safe_load(text)
        change(data)
        path = tmp_path / "changed.yaml"
        path.write_text(yaml.safe_dump(data))
        if message is None:
            assert main(["modes", str(path), "--runup", str(tmp_path / "r.png"), "--runup-time", "600"]) == 2
            assert "a network run keeps at most 5,000,000 samples" in capsys.readouterr().err
        else:
            assert main(["sim", str(path), "--quiet"]) == 2
            assert message in capsys.readouterr().err


def test_a_belt_looped_round_two_pulleys_whose_errors_cancel_is_refused(tmp_path, capsys):
    """The backside idler moved above the belt (-2 pi in the turn count) and an inner idler put inside the loop
    (+2 pi): the count said one turn, and a belt looped round both (wraps of 309 and 264 deg) ran. The spans at the
    idler cross (an alpha loop): refused, naming it; each error alone was refused already."""
    import yaml

    from belt_drive_ros.cli import main
    from belt_drive_ros.io.scenes import _shipped_text

    data = yaml.safe_load(_shipped_text("fead_i4", "networks"))
    next(p for p in data["pulleys"] if p["name"] == "idler")["centre"] = [0.0, 0.40]
    data["pulleys"].append({"name": "ghost", "role": "idler", "centre": [-0.09, 0.10], "radius": 0.02,
                            "inertia": 1e-4})
    path = tmp_path / "looped.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    assert main(["scenes", str(path)]) == 2
    assert "pulleys.idler: the spans water_pump -> idler and idler -> power_steering cross: not a simple loop" \
        in capsys.readouterr().err
