"""``belt-drive bench network_slip``: real-time factor of a belt network's slipping tier.

Cases (all warm: the kernel loaded from its cache and each case run once before timing):

* ``fead_i4`` as shipped (never reaches its capstan limits: every pulley sticks throughout);
* ``fead_i4 slipping``: installed tension 150 N and the alternator's load stepping from 1.5 to 12 N m at
  0.3 s (a full-field alternator): the crank slips at the start and at every firing pulse for a while,
  the alternator after the step;
* ``paper_network slipping``: the paper's drive as a network at 100 N installed tension (slips in the
  soft start, re-sticks);

Real-time factor = simulated seconds / wall seconds of the whole ``simulate_slipping`` call (outputs
included), the best of the repeats. Then the node's tick (:class:`~belt_drive_ros.ros.network_stepper.NetworkStepper`,
1 ms ticks, the alternator's load held anew each tick) on ``fead_i4`` at 150 N with a greasy pulsing
alternator (it slides and sticks every pulse), slipping tier beside the flexible tier in the same run, at 1
and 10 steps per tick: median and p99 of ``advance`` and the median of ``sample`` (the tick's outputs).
Writes ``network_slip.csv`` into ``--out``.
"""

from __future__ import annotations

import csv
import time
from collections import Counter
from importlib import resources
from pathlib import Path


def _scene(name: str, tension: float | None = None, alternator_step: float | None = None):
    from ..io.inputs import parse_yaml
    from ..core.network.scene import NetworkScene

    data = parse_yaml((resources.files("belt_drive_ros") / "scenes" / "networks" / f"{name}.yaml").read_text(), name)
    if tension is not None:
        data["belt"]["installed_tension"] = tension
    for p in data["pulleys"]:
        if alternator_step is not None and p["name"] == "alternator":
            p["torque"] = {"type": "step", "initial": 1.5, "final": alternator_step, "time": 0.3}
    return NetworkScene.from_mapping(data, name)


def _best(fn, repeats: int) -> tuple[float, object]:
    best, out = float("inf"), None
    for _ in range(repeats):
        t = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t)
    return best, out


def node_ticks(ticks: int) -> list:
    """Rows of the node tick study (module docstring): wall time per tick [us] of ``advance`` and ``sample``."""
    import numpy as np

    from ..core.network.scene import NetworkScene
    from ..ros.network_stepper import NetworkStepper

    rows = []
    for dt in (1e-3, 1e-4):
        from ..io.inputs import parse_yaml

        data = parse_yaml((resources.files("belt_drive_ros") / "scenes" / "networks" / "fead_i4.yaml").read_text(), "fead_i4")
        data["belt"]["installed_tension"] = 150.0
        data.update(dt=dt, duration=ticks * 1e-3)
        for p in data["pulleys"]:
            if p["name"] == "alternator":
                p["mu"] = 0.3
                p["torque"] = {"type": "sine", "mean": 2.0, "amplitude": 3.0, "frequency": 40.0}
        scene = NetworkScene.from_mapping(data, "fead_i4_greasy")
        sub = int(round(1e-3 / dt))
        alternator = [p.name for p in scene.pulleys].index("alternator")
        for tier in ("slipping", "flexible"):
            stepper = NetworkStepper(scene, tier=tier)
            x = stepper.advance(stepper.initial(), 0, sub)
            advance, sample = np.empty(ticks - 1), np.empty(ticks - 1)
            for k in range(1, ticks):
                stepper.hold(alternator, 2.0 + 3.0 * np.sin(2 * np.pi * 40.0 * k * 1e-3))
                t0 = time.perf_counter()
                x = stepper.advance(x, k * sub, (k + 1) * sub)
                t1 = time.perf_counter()
                stepper.sample((k + 1) * sub, x)
                advance[k - 1], sample[k - 1] = t1 - t0, time.perf_counter() - t1
            rows.append({"case": f"node tick, {sub} step(s)", "tier": tier, "duration_s": ticks * 1e-3, "steps": (ticks - 1) * sub,
                         "wall_s": float(advance.sum()), "x_real_time": (ticks - 1) * 1e-3 / float(advance.sum()),
                         "us_per_step": 1e6 * float(np.median(advance)) / sub, "events": 0,
                         "what": f"advance median {1e6 * np.median(advance):.0f} us, p99 {1e6 * np.percentile(advance, 99):.0f} us; "
                                 f"sample median {1e6 * np.median(sample):.0f} us"})
    return rows


def run(out: Path, quick: bool = False, quiet: bool = False) -> dict:
    from ..core.network.slip import simulate_slipping

    repeats = 2 if quick else 5
    cases = [
        ("fead_i4 (sticks)", _scene("fead_i4"), None),
        ("fead_i4 slipping", _scene("fead_i4", 150.0, 12.0), None),
        ("paper_network slipping", _scene("paper_network", 100.0), 2.0),
    ]
    rows = []
    for label, scene, duration in cases:
        duration = scene.duration if duration is None else duration
        if quick:
            duration = min(duration, 0.2)
        simulate_slipping(None, scene, duration=duration)
        wall, result = _best(lambda: simulate_slipping(None, scene, duration=duration), repeats)
        steps = len(result.time) - 1
        kinds = Counter((e.pulley, e.kind) for e in result.events)
        rows.append({"case": label, "tier": "slipping (compiled)", "duration_s": duration, "steps": steps,
                     "wall_s": wall, "x_real_time": duration / wall, "us_per_step": 1e6 * wall / steps,
                     "events": len(result.events),
                     "what": ", ".join(f"{p} {k} x{c}" for (p, k), c in sorted(kinds.items())) or "every pulley sticks"})
    rows += node_ticks(2000 if not quick else 300)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "network_slip.csv"
    with open(path, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    if not quiet:
        print(f"{'case':26s} {'tier':32s} {'sim s':>6s} {'steps':>7s} {'wall s':>8s} {'x real time':>11s} {'us/step':>8s}  events")
        for r in rows:
            print(f"{r['case']:26s} {r['tier']:32s} {r['duration_s']:6.2f} {r['steps']:7d} {r['wall_s']:8.4f} "
                  f"{r['x_real_time']:11.1f} {r['us_per_step']:8.2f}  {r['events']} {r['what']}")
    return {"csv": path, "rows": rows}
