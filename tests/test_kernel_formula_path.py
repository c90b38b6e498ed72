"""The general time loop (``kernel.wheel_steps``) evaluates profiles that are each one formula row from numbers read
once per call, with no dispatcher call per stage or fixed-point iteration: it must give the floats the dispatcher
gives. The same formulas behind a schedule whose one period covers every time take the dispatcher's path."""

import numpy as np
import pytest

from belt_drive_ros.core.kernel_loop import KernelLoop
from belt_drive_ros.core.model import make_model
from belt_drive_ros.core.profile_data import MOTOR_LINE, POLYNOMIAL, SCHEDULE, SINE, ProfileBuilder
from belt_drive_ros.core.simulate import Simulator
from belt_drive_ros.io.scenes import load_scene

ROWS = {
    "motor line, polynomial": ((MOTOR_LINE, 30.0, 300.0, 0.2), (POLYNOMIAL, 0.5, 0.02, 1e-4)),
    "sine, polynomial": ((SINE, 12.0, 4.0, 60.0, 0.3), (POLYNOMIAL, -1.0, 0.05, 0.0)),
}


def _data(row, scheduled: bool):
    builder = ProfileBuilder()
    if not scheduled:
        builder.row(*row)
        return builder.build()
    head = builder.reserve()
    offset, n = builder.table([-1.0e9], [1.0e9])  # one period [-1e9, 1e9) s: always the active row
    active = builder.row(*row)
    builder.fill(head, SCHEDULE, offset, n, active, builder.row(*row))
    return builder.build()


@pytest.mark.parametrize("method", ["trapezoidal", "etd4"])
@pytest.mark.parametrize("rows", list(ROWS))
def test_formula_rows_step_as_the_dispatcher_steps_them(method, rows):
    scene = load_scene("paper")
    sim = Simulator(make_model("flexible", scene.params), scene.drive, scene.load, method, 1e-3, check_stability=False)
    plant, scheme = sim.stepper.plant, sim.integrator.scheme
    x0 = np.ascontiguousarray(scene.initial_state.vector("flexible", scene.params.ratio), dtype=float)
    times = 1e-3 * np.arange(401, dtype=float)
    outs = []
    for scheduled in (False, True):
        drive, load = (_data(r, scheduled) for r in ROWS[rows])
        loop = KernelLoop(scheme, 1e-3, plant.wheel_map, (False, False), drive, load, (), None)
        out = np.empty((400, 4))
        done = _wheel_steps(loop, times, x0, out)  # (linear_steps sends an explicit method to its 2-/4-state loop)
        assert done[:2] == (400, 0), done
        outs.append(out)
    assert np.array_equal(outs[0], outs[1])
    assert np.all(np.isfinite(outs[0])) and np.ptp(outs[0][:, 2]) > 0.0  # the drive moved


def _wheel_steps(loop, times, x, out):
    """``kernel.wheel_steps`` on the arrays ``loop`` packs (as ``linear_steps`` unpacks them), P = 2."""
    from belt_drive_ros.core import kernel

    reals, ints, dp, lp = loop.reals, loop.ints, loop._dp, loop._lp
    n, s, E, rows, cols = (int(v) for v in ints[:5])
    at = ints[kernel.HEADER : kernel.HEADER + len(kernel.SECTIONS) + 1]
    k0 = kernel.HEADER + len(kernel.SECTIONS) + 1
    nd = dp.shape[0]
    kinds, dk, lk = ints[k0 : k0 + s], ints[k0 + s : k0 + s + nd], ints[k0 + s + nd :]
    part = [reals[at[j] : at[j + 1]] for j in range(len(kernel.SECTIONS))]
    return kernel.wheel_steps(
        times, x, out, -np.inf, np.inf, 1.0e5, part[0].reshape((1, 4, n)), kinds, part[1], part[2].reshape((s, rows, cols)),
        part[3].reshape((1, n, cols)), int(ints[5]), float(part[4][0]), int(ints[6]), np.array([0, 0], dtype=np.int64),
        np.zeros(2, dtype=np.int64), dk, dp, part[7], part[8], lk, lp, part[9], part[10], part[5].reshape((E, 5)), part[6],
    )  # fmt: skip
