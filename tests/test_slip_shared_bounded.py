"""What one scene's slipping engine keeps between runs (slip_run._shared_phases) stays bounded across step lengths.

A lazy :class:`~belt_drive_ros.core.slip_run.SlippingSimulator` shares its steppers and packed loops with the
scene's other simulators per method, step, options and thread (``SlippingSimulator._built``), and the accuracy
rerun keeps a whole simulator per step (``slip_run.rerun_simulator``). The scene's entry is dropped only when
eight other scenes are used after it: a convergence study of one scene over many steps (each run adds its step's,
2 dt's and dt / 2's steppers, loops and rerun simulators, ~250 kB a step for bsg_start) grew without bound. Only
the entries of the steps used last are kept; a step whose entries were dropped is built again (the same numbers:
what is kept holds no state between runs), so its results are the same floats.
"""

from __future__ import annotations

import numpy as np

from belt_drive_ros.core import slip_run
from belt_drive_ros.core.params import BeltDriveParams
from belt_drive_ros.core.sources import Constant


def _per_step(shared: dict) -> int:
    return sum(1 for k in list(shared) if isinstance(k, tuple) and len(k) == 5)


def test_a_scene_keeps_the_entries_of_its_last_steps_only():
    params, drive, load = BeltDriveParams(), Constant(3000.0), Constant(0.0)
    shared = None
    for j in range(150):
        sim = slip_run.rerun_simulator(params, drive, load, "etd4", 1e-3 * (1.0 + j / 200.0))
        shared = sim._shared
        sim.slip_phases()
    assert sim._shared is shared  # (one scene: its entry kept throughout)
    assert _per_step(shared) <= slip_run._STEP_ENTRIES < 150


def test_a_step_built_again_after_its_entries_were_dropped_gives_the_same_floats():
    params, drive, load = BeltDriveParams(), Constant(3000.0), Constant(0.0)
    x0 = np.zeros(5)

    def run(dt):
        sim = slip_run.SlippingSimulator(params, drive, load, "etd4", dt, check_stability=False, lazy=True)
        time, states, modes, sigmas = sim.run(0.02, x0)
        return time, states, modes, sigmas, [(e.kind, e.time, e.sigma) for e in sim.events]

    first = run(1e-3)
    assert len(first[4]) > 0  # the belt slips
    for j in range(1, slip_run._STEP_ENTRIES + 5):  # every entry of 1 ms dropped
        slip_run.rerun_simulator(params, drive, load, "etd4", 1e-3 * (1.0 + j / 400.0))
    again = run(1e-3)
    for a, b in zip(first[:4], again[:4]):
        assert np.array_equal(a, b)
    assert first[4] == again[4]
