"""``belt-drive sim NETWORK``: a belt network's run (linear tier), its summary, a CSV or MCAP named by pulley and span;
``belt-drive sim REC.mcap`` of a network node's recording: its exact re-simulation."""

from __future__ import annotations

import math
import time

#: most samples a network run keeps in memory (network runs do not stream yet)
MAX_SAMPLES = 5_000_000


def check_samples(option: str, duration: float, dt: float) -> None:
    """Refuse (SceneError naming ``option``) a network run of ``duration`` [s] at ``dt`` [s] holding more than
    :data:`MAX_SAMPLES` samples (a run keeps every sample in memory: ``sim``, ``modes --runup``)."""
    from ..core.errors import SceneError

    if duration / dt + 1 > MAX_SAMPLES:
        raise SceneError(f"{option}: {duration / dt:.3g} steps of dt = {dt:g} s; a network run keeps at most "
                         f"{MAX_SAMPLES:,} samples in memory (it does not stream yet)")


def _refuse_unsupported(args) -> None:
    from ..core.errors import SceneError

    given = [flag for flag, value in (("--v-eps", getattr(args, "v_eps", None)),
                                      ("--method-option", args.method_option), ("--torque-bag", args.torque_bag),
                                      ("--bag-folder", args.bag_folder),
                                      ("--tolerance", getattr(args, "tolerance", None) is not None)) if value]
    if given:
        raise SceneError(f"{given[0]}: not available for a belt network scene yet (docs/serpentine.md says what "
                         "a network run takes)")


def columns(scene, run):
    """``(names, table)``: time, per pulley angle/speed/belt torque/hub load/friction use (and, on the slipping tier,
    slip 0/1 and slip speed [m/s], as the MCAP's topics), per span tension and slack, arm angle."""
    import numpy as np

    names, cols = ["time"], [run.time]
    slipping = getattr(run, "slip_state", None) is not None
    for i, p in enumerate(scene.pulleys):
        signals = [("angle", run.angle), ("speed", run.speed), ("belt_torque", run.belt_torque),
                   ("hub_load", run.hub_load), ("friction_use", run.friction_use)]
        if slipping:
            signals += [("slip", run.slip), ("slip_speed", run.slip_speed)]
        for what, data in signals:
            names.append(f"{p.name}/{what}")
            cols.append(data[:, i])
    for j, span in enumerate(scene.span_names()):
        names += [f"spans/{span}/tension", f"spans/{span}/slack"]
        cols += [run.tension[:, j], run.slack[:, j].astype(float)]
    if run.arm_angle is not None:
        names.append("tensioner_arm/angle")
        cols.append(run.arm_angle)
    return names, np.column_stack(cols)


def run_network(args) -> int:
    import numpy as np

    from ..core.errors import IntegratorError, SceneError
    from ..core.integrators import method_class
    from ..core.network.simulate import simulate
    from ..io.scenes import load_network
    from ..io.atomic import atomic_output, check_output

    _refuse_unsupported(args)
    scene = load_network(args.scene)
    dt = scene.dt if args.dt is None else args.dt
    duration = scene.duration if args.duration is None else args.duration
    if not (math.isfinite(dt) and 1e-7 <= dt <= 1.0):
        raise SceneError(f"--dt: {dt!r} s is outside [1e-07, 1] s")
    if not (math.isfinite(duration) and 0.0 < duration <= 1.0e7):
        raise SceneError(f"--duration: {duration!r} s is outside (0, 1e7] s")
    if getattr(args, "start_time", None) is not None:  # (mcap loads for an MCAP output only)
        from ..io.recording import check_stamp_span

        check_stamp_span(args.start_time, duration)
    check_samples("--duration", duration, dt)
    method = scene.method if args.method is None else args.method
    if method == "auto":
        raise SceneError("--method auto: not available for a belt network scene (its run steps the method named, "
                         f"the scene's by default: {scene.method}); name a method instead")
    try:
        method_class(method)
    except IntegratorError as exc:
        raise IntegratorError(f"--{exc}") from None
    if args.out is not None:
        if args.out.suffix.lower() not in (".csv", ".mcap"):
            raise SceneError(f"--out {args.out}: a network run writes .csv or .mcap")
        check_output(args.out, args.force, "output")
    if args.plot is not None:
        if args.plot.suffix.lower() != ".png":
            raise SceneError(f"--plot {args.plot}: a PNG file (.png)")
        check_output(args.plot, args.force, "plot")
    start = time.perf_counter()
    run = simulate(scene, duration=duration, dt=dt, method=args.method, model=args.model or "auto")
    wall = time.perf_counter() - start
    print(f"{scene.name}: belt network, {run.tier} tier, {run.method} at dt = {dt:g} s, {duration:g} s simulated "
          f"in {wall:.2f} s ({duration / wall:.2f}x real time, loading the compiled kernels included: a second "
          "run in one process, as from Python, is far faster)")
    for line in (run.reason, f"accuracy: {run.accuracy}" if run.accuracy else ""):
        if line:
            print(line)
    print(f"{'pulley':16s} {'speed end [rad/s]':>18s} {'belt torque end [N m]':>22s} {'hub load max [N]':>17s} "
          f"{'friction use max':>17s}")
    for i, p in enumerate(scene.pulleys):
        print(f"{p.name:16s} {run.speed[-1, i]:18.3f} {run.belt_torque[-1, i]:22.3f} {run.hub_load[:, i].max():17.1f} "
              f"{run.friction_use[:, i].max():17.3f}")
    print(f"{'span':30s} {'tension min [N]':>16s} {'max [N]':>9s}  slack")
    for j, span in enumerate(scene.span_names()):
        slack = "yes" if run.slack[:, j].any() else "no"
        print(f"{span:30s} {run.tension[:, j].min():16.1f} {run.tension[:, j].max():9.1f}  {slack}")
    if run.arm_angle is not None:
        lo, hi = np.degrees(run.arm_angle.min()), np.degrees(run.arm_angle.max())
        print(f"tensioner arm: {lo:.3f} .. {hi:.3f} deg ({hi - lo:.3f} deg swing)")
    onset = run.capstan_onset(scene)
    if onset and run.tier != "slipping":
        print(f"capstan limit: {onset[0]} reaches it first at t = {onset[1]:.6g} s (friction use {onset[2]:.3g}); "
              f"past that time this {run.tier} run is not valid: model auto or slipping runs the slipping tier")
    if args.out is not None and args.out.suffix.lower() == ".mcap":
        _write_mcap(args, scene, run, run.method, dt)
    elif args.out is not None:
        names, table = columns(scene, run)
        with atomic_output(args.out, args.force, mode="w") as fh:
            fh.write(",".join(names) + "\n")
            np.savetxt(fh, table, delimiter=",", fmt="%.17g")
        print(f"wrote {args.out} ({len(table)} rows, {len(names)} columns)")
    if args.plot is not None:
        from ..io.network_plot import plot_network_run

        with atomic_output(args.plot, args.force, what="plot") as fh:
            plot_network_run(scene, run, fh)
        print(f"wrote {args.plot}")
    return 0


#: messages per second of a network MCAP (the node's default tick rate) [Hz]
OUTPUT_RATE = 1000.0


def _write_mcap(args, scene, run, method: str, dt: float) -> None:
    """The run as the node publishes it: one sample per 1 ms tick (every step if dt does not divide it)."""
    import time as _time

    from ..io.atomic import atomic_output
    from ..io.network_bag import scene_text, write_network_mcap
    from ..io.recording import output_stride
    from ..ros.network_stepper import NetworkStepper

    stride = output_stride(dt, OUTPUT_RATE)
    rows = range(0, len(run.time), stride)
    stepper = NetworkStepper(scene, method, dt, tier=run.tier)
    states = stepper.run(len(run.time) - 1)  # the loop's own states (the run's, bit for bit)
    start = _time.time_ns() if args.start_time is None else int(args.start_time)
    with atomic_output(args.out, args.force, what="output") as fh:
        counts = write_network_mcap(stepper, scene_text(args.scene), states[rows.start::stride], list(rows), fh,
                                    force=True, start_time_ns=start)
    print(f"wrote {args.out} ({sum(counts.values())} messages on {len(counts)} topics)")


def resimulate(args) -> int:
    """``belt-drive sim REC.mcap``: step a network recording's scene tick by tick with the inputs it applied."""
    import numpy as np

    from ..core.errors import SceneError
    from ..io.atomic import OutputRefused, atomic_output, check_output
    from ..io.inputs import input_replaced
    from ..io.network_bag import read_network_recording, write_network_mcap
    from ..ros.network_stepper import NetworkStepper

    rec = read_network_recording(args.scene)
    if args.out is not None:
        if args.out.suffix.lower() != ".mcap":
            raise SceneError(f"--out {args.out}: the re-simulation of a recording writes .mcap")
        if input_replaced(args.out, [args.scene]) is not None:
            raise OutputRefused(f"--out {args.out}: would replace {args.scene}, which this run reads; write elsewhere")
        check_output(args.out, args.force, "output")
    stepper = NetworkStepper(rec.scene, rec.method, rec.dt, tier=rec.tier or None)  # (the tier the node stepped)
    sub = int(round(rec.tick_ns * 1e-9 / rec.dt))
    ticks = int(round((rec.end_ns - rec.start_ns) / rec.tick_ns))
    x = stepper.initial()
    states = np.empty((len(rec.ticks), x.size))
    changes, c = sorted(rec.held), 0
    start = time.perf_counter()
    last = 0
    for row, j in enumerate(rec.ticks):  # the node's ticks: integrate to each, then take the inputs held from it
        x = stepper.advance(x, last * sub, j * sub)
        last = j
        states[row] = x
        while c < len(changes) and changes[c][0] <= j * sub:
            stepper.hold(changes[c][1], changes[c][2])
            c += 1
    wall = time.perf_counter() - start
    skipped = ticks + 1 - len(rec.ticks)
    print(f"re-simulated {args.scene}: {rec.scene.name}, {rec.method} at dt = {rec.dt:g} s, {ticks} ticks of "
          f"{rec.tick_ns / 1e9:g} s ({len(rec.ticks)} recorded" + (f", {skipped} integrated over by the node" if skipped else "")
          + f"), {len(changes)} input changes, in {wall:.2f} s")
    if args.out is not None:
        for i in range(len(stepper.held)):
            stepper.hold(i, None)
        with atomic_output(args.out, args.force, what="output") as fh:
            counts = write_network_mcap(stepper, rec.text, states, [j * sub for j in rec.ticks], fh, force=True,
                                        start_time_ns=rec.start_ns, held=changes, namespace=rec.namespace,
                                        received=rec.received)
        print(f"wrote {args.out} ({sum(counts.values())} messages on {len(counts)} topics)")
    return 0


def pulley_statements(scene, run) -> list:
    """One line per pulley, span group and the arm: what each did in ``run`` (the demo's words, SI + rpm)."""
    import numpy as np

    rpm = 30.0 / math.pi
    tail = slice(len(run.time) // 2, None)  # the second half: after the start
    lines = []
    for i, p in enumerate(scene.pulleys):
        w = run.speed[tail, i]
        torque = run.belt_torque[tail, i]
        use = run.friction_use[:, i]
        power = float(np.mean(torque * w))  # the belt's power into the pulley [W] (the belt torque acts on it)
        flow = ("gives {:.2f} kW to the belt" if power < 0 else "takes {:.2f} kW from the belt").format(abs(power) / 1e3)
        flow = flow if abs(power) >= 5.0 else "no power"
        what = {"driver": "drives the belt", "accessory": "is driven", "tensioner": "tensions the belt",
                "idler": "guides the belt"}.get(p.role, p.role)
        grip = (f"sticks ({use.max():.0%} of its capstan limit at most)" if use.max() < 1.0 else
                f"reaches its capstan limit at t = {run.time[int(np.argmax(use >= 1.0))]:.4g} s: it would slip there")
        lines.append(f"  {p.name:15s} {what:17s} {np.mean(w) * rpm:7.0f} rpm mean ({np.ptp(w) * rpm:6.1f} rpm "
                     f"ripple), belt torque {round(float(np.mean(torque)), 2) + 0.0:+7.2f} N m ({flow}), "
                     f"hub load up to {run.hub_load[:, i].max():5.0f} N; {grip}")
    lo, hi = run.tension.min(axis=0), run.tension.max(axis=0)
    tight, slack = int(np.argmax(hi)), int(np.argmin(lo))
    names = scene.span_names()
    lines.append(f"  spans           tightest {names[tight]} up to {hi[tight]:.0f} N, slackest {names[slack]} down to "
                 f"{lo[slack]:.0f} N; " + ("no span goes slack" if not run.slack.any() else
                                          "SLACK: " + ", ".join(n for j, n in enumerate(names) if run.slack[:, j].any())))
    if run.arm_angle is not None:
        a = np.degrees(run.arm_angle[tail])
        lines.append(f"  tensioner arm   at {a.mean():.2f} deg, swinging {np.ptp(a):.3f} deg")
    return lines


def demo_network(name: str, mcap_path) -> None:
    """``make demo``'s network part: the scene's run, what each pulley did, and its MCAP."""
    import argparse

    from ..io.scenes import load_network
    from ..core.network.simulate import simulate

    scene = load_network(name)
    start = time.perf_counter()
    run = simulate(scene)
    wall = time.perf_counter() - start
    print(f"  {scene.description}")
    print(f"  {scene.duration:g} s simulated ({run.method} at dt = {scene.dt:g} s, {run.tier} tier) in {wall:.2f} s")
    print(f"  {run.reason}; {run.accuracy}")
    for line in pulley_statements(scene, run):
        print(line)
    args = argparse.Namespace(scene=name, force=True, out=mcap_path, start_time=None)
    _write_mcap(args, scene, run, scene.method, scene.dt)
