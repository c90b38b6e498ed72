"""``belt-drive bench network_slip``: real-time factor of a belt network's slipping tier.

Cases (all warm: the kernel loaded from its cache and each case run once before timing):

* ``fead_i4`` as shipped (never reaches its capstan limits: every pulley sticks throughout);
* ``fead_i4 slipping``: installed tension 150 N and the alternator's load stepping from 1.5 to 12 N m at
  0.3 s (a full-field alternator): the crank slips at the start and at every firing pulse for a while,
  the alternator after the step;
* ``paper_network slipping``: the paper's drive as a network at 100 N installed tension (slips in the
  soft start, re-sticks);

beside the linear tier's Python reference run (``core/network/model.simulate``, method ``exact``) of
``fead_i4``. Real-time factor = simulated seconds / wall seconds of the whole ``simulate_slipping`` call
(outputs included), the best of the repeats. Writes ``network_slip.csv`` into ``--out``.
"""

from __future__ import annotations

import csv
import time
from collections import Counter
from importlib import resources
from pathlib import Path


def _scene(name: str, tension: float | None = None, alternator_step: float | None = None):
    from ..core.inputs import parse_yaml
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


def run(out: Path, quick: bool = False, quiet: bool = False) -> dict:
    from ..core.network.model import simulate as simulate_linear
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
    scene = _scene("fead_i4")
    duration = 0.05 if quick else 0.2
    wall, result = _best(lambda: simulate_linear(scene, duration=duration, method="exact"), 1 if quick else 2)
    steps = len(result.time) - 1
    rows.append({"case": "fead_i4 (sticks)", "tier": "linear (Python reference step)", "duration_s": duration, "steps": steps,
                 "wall_s": wall, "x_real_time": duration / wall, "us_per_step": 1e6 * wall / steps, "events": 0, "what": ""})
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
