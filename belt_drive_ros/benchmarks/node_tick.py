"""``belt-drive bench node-tick``: the node's tick compute in-process, compiled tick beside the general path.

Two :class:`~belt_drive_ros.ros.node.BeltDriveNode` in one process (no
executor spinning: the ticks are called here), the same scene and
parameters; one keeps its compiled common tick
(:mod:`belt_drive_ros.core.tick`), the other has it switched off, so every
tick goes through :meth:`~belt_drive_ros.core.stepper.Stepper.advance`
(or the slipping engine's) and the model's ``outputs``. They tick in turn,
each after a 1 ms sleep (the caches a 1 kHz node's tick finds: other
processes ran meanwhile), and the wall time of ``_tick`` (integration,
outputs, message encoding; what the tick thread's ``tick_compute_us``
measures, without the thread's own lock and sleep) is timed per call.
``joint_states`` counts as subscribed (its CDR is encoded every tick). The
drive torque (topic) changes every 10th tick, as a ~100 Hz controller
would; the compiled tick takes those too (the general path's clamps at the
change), the other node the general path. The two nodes' published values
are compared bit for bit at every tick.

Prints the median and p99 [us] per scene and path; no target is asserted
here (the issue's target, median <= 20 us on cold caches, is printed beside).

``--baseline DIR`` (another checkout, its numba cache warm): the compiled
tick of this tree and of ``DIR`` instead, each tree in its own child process
(``PYTHONPATH`` = the checkout, timed by this file's :func:`measure`),
alternating rounds of ticks; the median and p99 of all rounds per tree.
"""

from __future__ import annotations

import os
import statistics
import time
from pathlib import Path

CASES = (
    ("paper, flexible, drive_torque topic", (("drive_source", "topic"),)),
    ("truck_compressor, slipping, scene drive", (("scene", "truck_compressor"), ("model", "slipping"), ("drive_source", "scene"))),
    ("truck_compressor, slipping, drive_torque topic", (("scene", "truck_compressor"), ("model", "slipping"),
                                                        ("drive_source", "topic"))),
)
TARGET_US = 20.0


def _stats(samples) -> tuple[float, float]:
    s = sorted(samples)
    return statistics.median(s) / 1e3, s[int(0.99 * (len(s) - 1))] / 1e3


def measure(params, ticks: int, sleep: float = 0.001, general: bool = True) -> dict:
    """Median/p99 [us] of both paths' ticks and whether their values agreed at every tick; ``general=False``:
    the compiled tick alone (its samples [ns] under ``samples``)."""
    from rclpy.parameter import Parameter

    from ..ros.executors import ros_session
    from ..ros.node import BeltDriveNode

    with ros_session() as ctx:
        over = [Parameter("tick_thread", value=False)] + [Parameter(k, value=v) for k, v in params]
        nodes = [BeltDriveNode(context=ctx, parameter_overrides=over) for _ in range(2 if general else 1)]
        try:
            if general:
                nodes[1].sim._tick_kernel = None  # the general path: Stepper.advance + model.outputs every tick
            for node in nodes:
                node.refresh_subscriber_counts()
                node._readers["joint_states"] = 1  # joint_states encoded every tick (a subscriber)
                node._count_listeners()
            tick = nodes[0].sim.settings.tick_ns
            t0 = time.time_ns() // tick * tick
            for node in nodes:
                node._tick(t0, True)
            samples = ([], [])
            same = True
            clock = time.perf_counter_ns
            for k in range(1, ticks):
                now = t0 + k * tick
                for j, node in enumerate(nodes):
                    if k % 10 == 0:
                        node.drive.receive(1.0 + 1e-3 * (k % 70), now - 1, node.sim.settings)
                    time.sleep(sleep)
                    start = clock()
                    node._tick(now, True)
                    samples[j].append(clock() - start)
                same = same and list(nodes[0]._last[0]) == list(nodes[-1]._last[0])
            warm = ticks // 20
            if not general:
                return {"samples": samples[0][warm:]}
            return {"compiled": _stats(samples[0][warm:]), "general": _stats(samples[1][warm:]), "identical": same,
                    "compiled_ticks": sum(1 for _ in samples[0])}  # fmt: skip
        finally:
            for node in nodes:
                node.destroy_node()


#: what a child process of one tree runs for ``--baseline``: this file (argv[2], loaded as a module of the tree's
#: package: both trees timed by the same code), the compiled tick's samples [ns] of argv[1] ticks per case; the
#: first line names the tick kernel that ran
_CHILD = r"""
import importlib.util, json, sys
from belt_drive_ros.core import tick
spec = importlib.util.spec_from_file_location("belt_drive_ros.benchmarks._node_tick_timing", sys.argv[2])
bench = importlib.util.module_from_spec(spec)
spec.loader.exec_module(bench)
print(tick.__file__)
print(json.dumps([bench.measure(params, int(sys.argv[1]), general=False)["samples"] for _, params in bench.CASES]))
"""


def side_by_side(baseline: Path, ticks: int, rounds: int) -> list:
    """Per case ``(this tree's samples, the baseline's)`` [ns] of the compiled tick: each tree in its own child
    process, alternating ``rounds`` times (both trees on the same load)."""
    from .common import alternate_trees

    samples = [([], []) for _ in CASES]
    for j, figures in alternate_trees(baseline, _CHILD, (str(ticks), __file__), rounds, "node-tick"):
        for case, got in zip(samples, figures):
            case[j].extend(got)
    return samples


def main(quick: bool = False, baseline: Path | None = None) -> int:
    ticks = 400 if quick else 4000
    if baseline is not None:
        rounds = 2 if quick else 4
        print(f"bench node-tick --baseline {baseline}: the compiled tick, {rounds} alternating rounds of "
              f"{ticks // rounds} ticks per tree and scene, 1 ms sleep before each (cold caches), "
              f"load average {os.getloadavg()[0]:.2f}")
        for (label, _), (new, old) in zip(CASES, side_by_side(baseline, ticks // rounds, rounds)):
            (nm, np_), (om, op) = _stats(new), _stats(old)
            print(f"  {label}")
            print(f"    this tree       median {nm:6.1f} us   p99 {np_:6.1f} us   [target median <= {TARGET_US:g} us: "
                  f"{'ok' if nm <= TARGET_US else 'MISSED'}]")
            print(f"    {Path(baseline).name:<15} median {om:6.1f} us   p99 {op:6.1f} us   (ratio {om / nm:.2f}x)")
        print(f"  load average after {os.getloadavg()[0]:.2f}")
        return 0
    print(f"bench node-tick: {ticks} ticks per path and scene, 1 ms sleep before each (cold caches), "
          f"load average {os.getloadavg()[0]:.2f}")
    for label, params in CASES:
        r = measure(params, ticks)
        (cm, cp), (gm, gp) = r["compiled"], r["general"]
        print(f"  {label}")
        print(f"    compiled tick   median {cm:6.1f} us   p99 {cp:6.1f} us   [target median <= {TARGET_US:g} us: "
              f"{'ok' if cm <= TARGET_US else 'MISSED'}]")
        print(f"    general path    median {gm:6.1f} us   p99 {gp:6.1f} us   (ratio {gm / cm:.2f}x)")
        print(f"    published values identical at every tick: {'yes' if r['identical'] else 'NO'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
