"""``belt-drive bench campaign``: the campaign figures, measured side by side in one run.

1. A tolerance Monte Carlo of ``paper`` (100,000 variants, 5 s each; belt
   stiffness and damping, inertias, pre-tension, friction vary) as
   ``belt-drive sweep`` runs it: the default local cluster (one worker
   process per CPU), wall time from the command's start (cluster start and
   stop included) and of the batches alone; the workers' CPU per
   variant-step (everything a worker does, over the variants and the
   ``paper`` steps of 5 ms).
1b. The compiled variant loop alone (:func:`~belt_drive_ros.core.kernel_variants.variant_steps`,
   in this process): CPU per variant-step of ``paper``'s ``lawson5`` run
   over 2,000 variants, beside a single run's compiled loop per step (the
   same kernel on one plant).
2. The same variants as a plain loop of single ``simulate()`` calls (a
   sample of them, in this process, BLAS single-threaded like the workers;
   runs/s), and the ratio of the two throughputs. ``simulate`` runs the
   stability and accuracy guards, which the ensemble does not (it runs the
   stability guard only for methods that are not exact on the belt mode);
   the loop without guards (``check_stability=False``) is measured too.
3. The campaign on 1 and on 2 worker processes, each cluster started
   beforehand (start time reported apart) and warmed up (every worker has
   run a batch), the same batches for both (8: four per worker on two):
   throughput ratio. Alternating 1, 2, 1, 2 and keeping the best rate of
   each, so that a burst of other work on the machine during one of them
   does not decide the ratio; and the workers' CPU time per run (user +
   system, from the workers themselves) with 1 and with 2 workers.
4. A fleet of 100 torque recordings generated from the shipped ones (the
   three truck bags, each scaled by 0.9 .. 1.1), replayed through
   ``bags/engine_idle.yaml`` and compared against their goldens (written
   by a first run) in one campaign.

Prints one table and writes ``campaign.csv``. Other work on the machine
slows every figure: the load average is printed, and the ratios, measured
side by side, are the figures to read.
"""

from __future__ import annotations

import csv
import os
import tempfile
import time
from pathlib import Path

#: variants of the Monte Carlo (``--quick``: QUICK_SAMPLES); the 1-vs-2-worker scaling runs SCALING_SAMPLES
SAMPLES, QUICK_SAMPLES, SCALING_SAMPLES = 100_000, 2_000, 10_000
MC = {
    "name": "paper_tolerances",
    "scene": "paper",
    "monte_carlo": {
        "samples": SAMPLES,
        "seed": 1,
        "vary": {
            "params.k": {"normal": 0.05},
            "params.c": {"normal": 0.1},
            "params.I_M": {"uniform": [0.95, 1.05]},
            "params.I_3": {"uniform": [0.9, 1.1]},
            "params.F_0": {"normal": 0.05},
            "params.mu": {"uniform": [0.9, 1.1]},
        },
    },
}
BAGS = Path(__file__).resolve().parents[2] / "bags"
FLEET_SOURCES = ("engine_idle", "engine_runup", "compressor_cycling")


def _campaign(data: dict, folder: Path):
    import yaml

    from ..campaign.spec import Campaign

    path = folder / f"{data['name']}.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return Campaign.load(path)


def make_fleet(folder: Path, count: int = 100) -> Path:
    """``count`` torque recordings (``/drive_torque``, 1 kHz) from the shipped truck bags, scaled 0.9 .. 1.1."""
    import dataclasses

    from ..io.scenes import load_scene
    from ..core.simulate import simulate
    from ..io.recording import write_result_mcap
    from ..io.torque_bag import scene_with_torque_bag

    folder.mkdir(parents=True, exist_ok=True)
    for k in range(count):
        name = FLEET_SOURCES[k % len(FLEET_SOURCES)]
        scene = scene_with_torque_bag(load_scene(BAGS / f"{name}.yaml"), BAGS / f"{name}_torque.mcap")
        factor = 0.9 + 0.2 * k / max(count - 1, 1)
        drive = dataclasses.replace(scene.drive, values=scene.drive.values * factor)
        run = simulate(dataclasses.replace(scene, drive=drive, model="flexible"))
        write_result_mcap(run, folder / f"{name}_{k:03d}.mcap", force=True, output_rate=1000.0,
                          topics=("drive_torque",), start_time_ns=0)
    return folder


def _cpu_seconds() -> tuple[float, float]:
    """(user, system) CPU seconds of this process (a worker's, through ``client.run``)."""
    import resource

    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime, usage.ru_stime


def _default_run(campaign, out: Path, progress: bool):
    """``run_campaign`` on the default local cluster as ``belt-drive sweep`` starts it; (its run, the workers' CPU [s])."""
    from distributed import Client

    from ..campaign.execute import local_cluster, run_campaign

    cluster = local_cluster(os.cpu_count() or 1)
    client = Client(cluster)
    try:
        before = client.run(_cpu_seconds)
        done = run_campaign(campaign, out, client=client, progress=progress)
        after = client.run(_cpu_seconds)
        return done, sum(sum(after[a]) - sum(before[a]) for a in after)
    finally:
        client.close()
        cluster.close()


def _scaling_run(campaign, out: Path, workers: int, batch_size: int) -> tuple[float, float, float, float]:
    """(runs/s of the batches, cluster start [s], workers' CPU [s], of it system [s]) on ``workers`` warm workers."""
    from distributed import Client, wait

    from ..campaign.execute import local_cluster, portable_of, run_batch, run_campaign

    t0 = time.perf_counter()
    cluster = local_cluster(workers)  # as belt-drive sweep starts it
    client = Client(cluster)
    start = time.perf_counter() - t0
    try:
        portable, rows = portable_of(campaign), campaign.variants().to_dict("records")[:64]
        warm = [client.submit(run_batch, portable, rows, None, pure=False, workers=[addr])
                for addr in client.scheduler_info()["workers"]]  # fmt: skip
        wait(warm)
        before = client.run(_cpu_seconds)
        done = run_campaign(campaign, out, client=client, progress=False, batch_size=batch_size)
        after = client.run(_cpu_seconds)
        user = sum(after[a][0] - before[a][0] for a in after)
        system = sum(after[a][1] - before[a][1] for a in after)
        return len(done.table) / done.compute_wall, start, user + system, system
    finally:
        client.close()
        cluster.close()


def kernel_figures(count: int = 2000, repeats: int = 3) -> tuple[float, float]:
    """(CPU ns per variant-step of the variant loop, CPU ns per step of a single run's loop): ``paper``, lawson5 at 5 ms.

    The minimum over ``repeats`` of 200 steps of ``count`` variants (k, c, I_M varied) in one
    :func:`~belt_drive_ros.core.kernel_variants.variant_steps` call, and of 200,000 steps of the base
    scene's single run (:class:`~belt_drive_ros.core.kernel_loop.KernelLoop`), process CPU time.
    """
    import math

    import numpy as np

    from ..core.ensemble import Ensemble
    from ..core.integrators import method_class
    from ..core.kernel_variants import variant_steps
    from ..core.model import ModelStack, make_model
    from ..io.scenes import load_scene
    from ..core.stepper import SPEED_LIMIT, Plant

    scene = load_scene("paper")
    rng = np.random.default_rng(1)
    p = scene.params
    params = [p.replace(k=p.k * rng.uniform(0.9, 1.1), c=p.c * rng.uniform(0.8, 1.2), I_M=p.I_M * rng.uniform(0.95, 1.05))
              for _ in range(count)]  # fmt: skip
    loop = Ensemble(ModelStack("flexible", params), scene.drive, scene.load, scene.method, scene.dt)._loop(scene.dt)
    steps = 200
    times = np.arange(steps + 1) * scene.dt
    states = np.zeros((steps + 1, 4, count))  # (knots, states, variants)
    best = math.inf
    for _ in range(repeats):
        status = np.zeros(count, dtype=np.int64)
        c0 = time.process_time()
        variant_steps(times, states, 0, -math.inf, math.inf, SPEED_LIMIT, loop.reals, loop.tables, loop.ints,
                      loop._dp, loop._lp, status)  # fmt: skip
        best = min(best, time.process_time() - c0)
    per_variant_step = best / (count * steps) * 1e9
    plant = Plant(make_model("flexible", p), scene.drive, scene.load)
    single = plant.kernel_loop(method_class(scene.method)(plant.model.A, plant.model.B, scene.dt))
    n = 200_000
    times, out, best = np.arange(n + 1) * scene.dt, np.empty((n, 4)), math.inf
    for _ in range(repeats):
        c0 = time.process_time()
        single(times, np.zeros(4), out)
        best = min(best, time.process_time() - c0)
    return per_variant_step, best / n * 1e9


def run(out: Path, quick: bool = False, quiet: bool = False, samples: int | None = None) -> dict:
    """The figures (module docstring); ``samples``: variants of the Monte Carlo (default SAMPLES, QUICK_SAMPLES with ``quick``)."""
    from ..campaign.execute import loop_of_single_runs, run_campaign

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        count = samples if samples is not None else QUICK_SAMPLES if quick else SAMPLES
        data = dict(MC, monte_carlo=dict(MC["monte_carlo"], samples=max(int(count), 1)))
        campaign = _campaign(data, tmp)
        n = campaign.samples
        scaling = _campaign(dict(MC, name="paper_scaling",
                                 monte_carlo=dict(MC["monte_carlo"], samples=min(n, SCALING_SAMPLES))), tmp)  # fmt: skip
        kernel_ns, single_ns = kernel_figures(500 if quick else 2000)
        # 1. the Monte Carlo on the default cluster (one worker per CPU)
        load_start = os.getloadavg()[0]
        t0 = time.perf_counter()
        default, worker_cpu = _default_run(campaign, tmp / "mc_default", not quiet)
        wall_default = time.perf_counter() - t0
        steps = round(campaign.base.duration / campaign.base.dt)
        ensemble = int((default.table["ran"] == "ensemble").sum())
        single = int((default.table["ran"] == "single").sum())
        failed = int((default.table["error"] != "").sum())
        # 2. a loop of single simulate() calls on a sample of the same variants
        sample = default.table.drop(columns=[c for c in default.table.columns if not c.startswith("params.") and c != "variant"])
        sample = sample.iloc[:: max(n // (20 if quick else 200), 1)].to_dict("records")
        t0 = time.perf_counter()
        loop_of_single_runs(campaign, sample)
        loop_rate = len(sample) / (time.perf_counter() - t0)
        t0 = time.perf_counter()
        loop_of_single_runs(campaign, sample, check_stability=False)
        loop_rate_unguarded = len(sample) / (time.perf_counter() - t0)
        # 3. 1 worker against 2: clusters started and warmed up first, the same batches; alternating, best of two
        tries, starts, cpu = {1: [], 2: []}, {}, {1: [], 2: []}
        size = max(scaling.samples // 8, 1)
        for w in (1, 2) if quick else (1, 2, 1, 2):
            rate, starts[w], seconds, system = _scaling_run(scaling, tmp / f"mc_{w}_{len(tries[w])}", w, size)
            tries[w].append(rate)
            cpu[w].append((seconds, system))
        rates = {w: max(r) for w, r in tries.items()}
        per_run = {w: min(c for c, _ in cpu[w]) / scaling.samples * 1e3 for w in cpu}  # ms of worker CPU per run
        system_share = {w: sum(s for _, s in cpu[w]) / sum(c for c, _ in cpu[w]) for w in cpu}
        # 4. the fleet: 100 recordings, goldens from a first run, then replay and compare
        count = 12 if quick else 100
        fleet_dir = make_fleet(tmp / "fleet", count)
        fleet = {"name": "fleet", "scene": str(BAGS / "engine_idle.yaml"), "set": {"model": "flexible"},
                 "fleet": {"folder": str(fleet_dir)}}  # fmt: skip
        golden = run_campaign(_campaign(fleet, tmp), tmp / "fleet_golden", progress=False)
        fleet["fleet"]["golden"] = str(tmp / "fleet_golden" / "recordings")
        t0 = time.perf_counter()
        replay = run_campaign(_campaign(fleet, tmp), tmp / "fleet_new", progress=False)
        wall_fleet = time.perf_counter() - t0
        passed = int(replay.table["compare_passed"].astype(bool).sum())
        del golden
    rate_default = n / wall_default
    rows = [
        ("mc_variants", n, f"paper, 5 s each ({steps} steps of lawson5), 6 tolerances"),
        ("mc_wall_s", wall_default, f"default cluster ({default.workers} workers), start to results.parquet (target <= 20 s)"),
        ("worker_cpu_ns_per_variant_step", worker_cpu / (n * steps) * 1e9,
         "the workers' whole CPU (rigid estimate, lawson5 run, metrics, tables) / (variants x steps)"),
        ("kernel_ns_per_variant_step", kernel_ns, "variant_steps alone, lawson5, CPU per variant-step (target <= 50 ns)"),
        ("single_run_ns_per_step", single_ns, "the same kernel on one plant (a single run's loop), CPU per step"),
        ("mc_batches_wall_s", default.compute_wall, "the same from the first task sent to the last result written"),
        ("mc_ran_ensemble", ensemble, "variants stepped in an ensemble"),
        ("mc_ran_single", single, "variants run singly"),
        ("mc_failed", failed, ""),
        ("mc_rate_runs_per_s", rate_default, "wall, cluster start included"),
        ("load_average", os.getloadavg()[0],
         f"1-min load average at the end ({load_start:.2f} at the start), {os.cpu_count()} CPUs (other work slows every figure)"),
        ("loop_rate_runs_per_s", loop_rate, f"loop of single simulate() calls ({len(sample)} variants, 1 process)"),
        ("throughput_ratio", rate_default / loop_rate, "campaign (wall, start included) / loop of single runs"),
        ("loop_rate_unguarded_runs_per_s", loop_rate_unguarded, "the loop with simulate(check_stability=False)"),
        ("throughput_ratio_unguarded", rate_default / loop_rate_unguarded, "campaign / loop without the guards"),
        ("workers_2_vs_1", rates[2] / rates[1],
         f"{rates[1]:.0f} -> {rates[2]:.0f} runs/s (best of {len(tries[1])} alternating; all: "
         f"{', '.join(f'{r:.0f}' for r in tries[1])} / {', '.join(f'{r:.0f}' for r in tries[2])}), "
         f"{size}-variant batches on warm workers"),
        ("worker_cpu_ms_per_run", per_run[2],
         f"workers' CPU per run on 2 workers (1 worker: {per_run[1]:.2f} ms; system time {system_share[2]:.0%} / "
         f"{system_share[1]:.0%}); equal: the work does not grow with the workers, the wall ratio is then up to the free CPUs"),
        ("cluster_start_s", starts[2], f"2-worker LocalCluster start (1 worker: {starts[1]:.2f} s), not in the ratio"),
        ("fleet_recordings", count, "truck torque bags x 0.9 .. 1.1"),
        ("fleet_wall_s", wall_fleet, "replay + MCAP + compare against goldens, one campaign"),
        ("fleet_passed", passed, "recordings within the tube"),
    ]
    path = out / "campaign.csv"
    from ..io.atomic import atomic_output

    with atomic_output(path, force=True, mode="w") as fh:  # whole or not at all
        writer = csv.writer(fh)
        writer.writerow(["figure", "value", "note"])
        writer.writerows(rows)
    for name, value, note in rows:
        text = f"{value:.3g}" if isinstance(value, float) and not float(value).is_integer() else f"{value}"
        print(f"  {name:<22s} {text:>10s}  {note}")
    return {"csv": path, "png": path, "rows": rows}

