"""Long runs stream (issue 13): windows equal the whole run, outputs are written as the run goes, memory stays flat."""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

from belt_drive_ros.cli import main
from belt_drive_ros.commands import sim as sim_command
from belt_drive_ros.core import sources as S
from belt_drive_ros.core import stream as stream_module
from belt_drive_ros.io.scenes import load_scene
from belt_drive_ros.core.simulate import simulate
from belt_drive_ros.core.stream import Restart, stream
from belt_drive_ros.io import run_writers
from belt_drive_ros.io.run_writers import RunSummary
from msg_tools import block_writer


def _joined(windows):
    windows = [w for w in windows if not isinstance(w, Restart)]
    time = np.concatenate([w.time for w in windows])
    outputs = {k: np.concatenate([w.outputs[k] for w in windows]) for k in windows[0].outputs}
    energy = {k: np.concatenate([w.energy[k] for w in windows]) for k in windows[0].energy}
    return windows, time, outputs, energy


def _assert_same_run(whole, time, outputs, energy):
    np.testing.assert_allclose(time, whole.time, rtol=0, atol=1e-12)
    for name, values in whole.outputs.items():
        scale = max(1.0, float(np.max(np.abs(values))))
        np.testing.assert_allclose(outputs[name], values, rtol=0, atol=1e-9 * scale, err_msg=name)
    for name, values in whole.energy.items():
        scale = max(1.0, float(np.max(np.abs(values))))
        np.testing.assert_allclose(energy[name], values, rtol=0, atol=1e-9 * scale, err_msg=name)


@pytest.mark.parametrize("name, model", [("paper", "flexible"), ("e_motor_start", "rigid"), ("truck_compressor", "slipping")])
def test_windows_put_together_are_the_whole_run(name, model):
    scene = load_scene(name).with_overrides(duration=1.0)
    whole = simulate(scene, model=model)
    windows, time, outputs, energy = _joined(stream(scene, model=model, window_steps=23))
    assert len(windows) > 5 and len(time) == len(whole.time)
    _assert_same_run(whole, time, outputs, energy)
    summary = RunSummary()
    for w in windows:
        summary.add(w)
    assert summary.samples == len(whole.time)
    assert summary.final["omega_M"] == outputs["omega_M"][-1]
    assert summary.peak_deflection == np.max(np.abs(whole.outputs["relative_deflection"]))
    assert summary.onsets == sum(1 for e in whole.events if e[0] == "onset")


@pytest.mark.parametrize("model", ["flexible", "rigid"])
@pytest.mark.parametrize("open_loop", [False, True], ids=["closed-loop", "open-loop"])
def test_windowed_states_are_the_whole_runs_bit_for_bit(model, open_loop):
    """One compiled loop on one grid: cutting the run into windows changes no float (time-only torques too)."""
    scene = load_scene("paper").with_overrides(duration=1.0)
    if open_loop:
        scene = scene.with_overrides(drive=S.Step(0.0, 8.0, 0.25), load=S.Constant(2.0))
    whole = simulate(scene, model=model)
    windows = [w for w in stream(scene, model=model, window_steps=23) if not isinstance(w, Restart)]
    assert len(windows) > 5
    assert np.array_equal(np.concatenate([w.states for w in windows]), whole.states)


def test_auto_restarts_on_the_slipping_model_when_the_limit_is_passed():
    """truck_compressor's flexible run passes the capstan limit at ~0.58 s: the stream starts over, slipping."""
    scene = load_scene("truck_compressor").with_overrides(duration=1.0)
    items = list(stream(scene, window_steps=200))
    restarts = [i for i, w in enumerate(items) if isinstance(w, Restart)]
    assert len(restarts) == 1 and restarts[0] > 0
    assert all(w.model == "flexible" for w in items[: restarts[0]])
    after = items[restarts[0] + 1 :]
    assert after[0].time[0] == 0.0 and all(w.model == "slipping" for w in after)
    whole = simulate(scene)
    assert whole.model == "slipping"
    _, time, outputs, energy = _joined(after)
    _assert_same_run(whole, time, outputs, energy)


def test_auto_without_slip_streams_once():
    scene = load_scene("paper").with_overrides(duration=2.0)
    items = list(stream(scene, window_steps=50))
    assert not any(isinstance(w, Restart) for w in items)
    assert items[-1].choice.model == simulate(scene).choice.model == "flexible"


def test_the_guard_runs_beside_the_windows_and_gives_the_report_of_a_run_in_one_window(monkeypatch):
    """A run of several windows yields its first windows while its accuracy guard still runs (the windows do
    not depend on it); the last window carries the guard's report, the same as a run in one window."""
    import threading

    scene = load_scene("paper").with_overrides(duration=0.5)
    one = list(stream(scene, window_steps=10**6))
    assert len(one) == 1 and one[0].accuracy is not None
    gate, real = threading.Event(), stream_module.require_accurate

    def held(*args, **kwargs):  # the guard waits until the test has two windows
        gate.wait(5.0)
        return real(*args, **kwargs)

    monkeypatch.setattr(stream_module, "require_accurate", held)
    windows = stream(scene, window_steps=23)
    first, second = next(windows), next(windows)
    assert first.accuracy is None and second.accuracy is None  # yielded while the guard waits
    gate.set()
    rest = list(windows)
    assert repr(rest[-1].accuracy) == repr(one[0].accuracy)
    assert np.array_equal(np.concatenate([w.states for w in [first, second] + rest]), one[0].states)


def test_an_unstable_step_is_refused_by_a_run_in_windows_as_by_a_whole_run():
    """The guard's refusal (naming a step that works), not the run's divergence, however far the windows got."""
    from belt_drive_ros.core.errors import UnstableStepError

    truck = load_scene("truck_compressor")
    scene = truck.with_overrides(drive=S.Constant(50.0), load=S.Polynomial(0.0, 200.0), duration=0.5, model="flexible",
                                 method="exact", dt=2e-3)
    with pytest.raises(UnstableStepError) as whole:
        simulate(scene)
    with pytest.raises(UnstableStepError) as windows:
        list(stream(scene, window_steps=10))
    assert str(windows.value) == str(whole.value) and "stable and accurate" in str(whole.value)


# ------------------------------------------------------------------ the command
@pytest.fixture
def streamed(monkeypatch):
    """Make `belt-drive sim` stream every run, in small windows."""
    monkeypatch.setattr(sim_command, "STREAM_ABOVE", 0)
    monkeypatch.setattr(stream_module, "WINDOW_STEPS", 64)


@pytest.mark.parametrize("scene", ["paper", "truck_compressor"])
def test_streamed_csv_equals_the_in_memory_csv(tmp_path, capsys, monkeypatch, scene):
    assert main(["sim", scene, "--duration", "1", "--quiet", "--out", str(tmp_path / "memory.csv")]) == 0
    monkeypatch.setattr(sim_command, "STREAM_ABOVE", 0)
    monkeypatch.setattr(stream_module, "WINDOW_STEPS", 64)
    assert main(["sim", scene, "--duration", "1", "--quiet", "--out", str(tmp_path / "streamed.csv")]) == 0
    a = (tmp_path / "memory.csv").read_text().splitlines()
    b = (tmp_path / "streamed.csv").read_text().splitlines()
    assert a[0] == b[0] and len(a) == len(b)
    np.testing.assert_allclose(np.loadtxt(b[1:], delimiter=","), np.loadtxt(a[1:], delimiter=","), rtol=1e-9, atol=1e-9)
    out = capsys.readouterr().out
    memory, streamed_ = out.split("wrote")[0], out.split("wrote")[1]
    model = memory.splitlines()[1].split()[:2]
    assert model == streamed_.splitlines()[2].split()[:2]  # the same model (slipping for the truck)


def test_streamed_mcap_has_the_whole_runs_messages(tmp_path, monkeypatch):
    from msg_tools import summary as mcap_summary

    argv = ["sim", "paper", "--duration", "2", "--quiet", "--start-time", "0"]
    assert main(argv + ["--out", str(tmp_path / "memory.mcap")]) == 0
    monkeypatch.setattr(sim_command, "STREAM_ABOVE", 0)
    monkeypatch.setattr(stream_module, "WINDOW_STEPS", 37)
    assert main(argv + ["--out", str(tmp_path / "streamed.MCAP")]) == 0
    a, b = mcap_summary(tmp_path / "memory.mcap"), mcap_summary(tmp_path / "streamed.MCAP")
    counts = {t.topic: t.message_count for t in a.topics}
    assert counts == {t.topic: t.message_count for t in b.topics} and sum(counts.values()) > 0
    assert a.start_ns == b.start_ns and a.end_ns == b.end_ns and b.complete
    assert a.metadata_dict("scene")["samples"] == b.metadata_dict("scene")["samples"]
    from belt_drive_ros.io.torque_bag import scene_from_bag

    assert scene_from_bag(tmp_path / "streamed.MCAP") == scene_from_bag(tmp_path / "memory.mcap")


@pytest.mark.parametrize("duration", ["0.0123", "1.0023"])
def test_an_mcap_ends_where_the_run_does(tmp_path, monkeypatch, duration):
    """A duration that is no whole number of output periods (1 kHz): the file ended up to a period before the run
    (0.012 s of a 0.0123 s run; the summary's final state was in no file). It ends at the duration, with the run's
    last sample, in memory and streamed alike, and counts it in its scene record."""
    from msg_tools import read_topic, summary as mcap_summary

    from belt_drive_ros.core.simulate import simulate

    argv = ["sim", "truck_compressor", "--model", "flexible", "--duration", duration, "--quiet", "--start-time", "0"]
    assert main(argv + ["--out", str(tmp_path / "memory.mcap")]) == 0
    monkeypatch.setattr(sim_command, "STREAM_ABOVE", 0)
    monkeypatch.setattr(stream_module, "WINDOW_STEPS", 64)
    assert main(argv + ["--out", str(tmp_path / "streamed.mcap")]) == 0
    run = simulate(load_scene("truck_compressor"), model="flexible", duration=float(duration))
    for name in ("memory.mcap", "streamed.mcap"):
        path = tmp_path / name
        speed = read_topic(path, "/shaft_speed")
        times = speed.log_time_ns * 1e-9
        assert times[-1] == pytest.approx(float(duration), abs=1e-9) and np.all(np.diff(times) > 0), name
        assert times[-2] == pytest.approx(np.floor(float(duration) * 1000.0) / 1000.0, abs=1e-9), name
        assert speed.fields["data"][-1] == run["omega_M"][-1], name
        info = mcap_summary(path)
        assert int(info.metadata_dict("scene")["samples"]) == len(times), name


def _peak_bytes(argv) -> int:
    tracemalloc.start()
    try:
        assert main(argv) == 0
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


@pytest.mark.parametrize("ext", ["csv", "mcap"])
def test_memory_does_not_grow_with_the_duration(tmp_path, monkeypatch, ext):
    """A run 4x longer peaks at about the same memory: its peak grows by under 16 B per extra sample,
    where a run kept in memory needs ~300 B per sample.

    Time-only torques (no Python callback per step) keep tracing every
    allocation cheap; windows of 500 steps (and the auto choice's
    speed estimate in windows of 500) make both runs many windows. A first,
    untraced run loads what the process loads once (imports, compiled
    kernels, caches): otherwise the short run's peak would hold them and the
    comparison would depend on which tests ran before in the process.
    """
    from belt_drive_ros.core import accuracy_probes

    monkeypatch.setattr(sim_command, "STREAM_ABOVE", 0)
    monkeypatch.setattr(stream_module, "WINDOW_STEPS", 500)
    monkeypatch.setattr(accuracy_probes, "SURVEY_CHUNK", 500)
    monkeypatch.setattr(run_writers, "STREAM_CHUNK", 64 << 10)  # both runs fill many MCAP chunks
    # chunks compressed in threads: how many wait at once depends on the machine's load (up to 8 x ~100 kB:
    # ~11 B per extra sample, seen under load as 18-28 B); one at most keeps that out of the comparison
    monkeypatch.setattr(block_writer, "MAX_IN_FLIGHT", 1)
    scene = tmp_path / "steady.yaml"
    scene.write_text("extends: paper\ndrive: {type: ramp, start_value: 0.0, end_value: 3.0, start_time: 0.0, end_time: 1.0}\n"
                     "load: 1.0\n")
    base = 100 if ext == "csv" else 50  # MCAP encoding allocates per message: slow under tracemalloc
    dt = load_scene("paper").dt

    def run(duration: float, name: str) -> list:
        return ["sim", str(scene), "--duration", str(duration), "--quiet", "--force", "--out", str(tmp_path / f"{name}.{ext}")]

    assert main(run(base, "warm")) == 0  # what a process loads once, loaded before the tracing
    short = _peak_bytes(run(base / 2, "short"))
    long = _peak_bytes(run(2 * base, "long"))
    rows = 2 * base / dt
    per_sample = (long - short) / (1.5 * base / dt)  # measured: ~3 B (CSV), ~2 B (MCAP): per-window bookkeeping
    assert per_sample < 16, (short, long, per_sample)
    if ext == "csv":
        assert long < rows * 8 * 4  # less than 4 floats per sample of the run
        assert len((tmp_path / "long.csv").read_text().splitlines()) == rows + 2


def test_plot_of_a_long_run_is_refused_up_front_with_a_decimation(tmp_path, capsys):
    code = main(["sim", "paper", "--duration", "86400", "--plot", str(tmp_path / "p.png"), "--quiet"])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "--plot-every 70" in err
    assert list(tmp_path.iterdir()) == []


def test_plot_every_draws_a_streamed_run(tmp_path, capsys, streamed, monkeypatch):
    monkeypatch.setattr(sim_command, "PLOT_SAMPLES", 300)
    argv = ["sim", "paper", "--duration", "5", "--quiet", "--plot", str(tmp_path / "p.png")]
    assert main(argv) == 2 and "--plot-every 4" in capsys.readouterr().err
    assert main(argv + ["--plot-every", "4", "--out", str(tmp_path / "run.csv")]) == 0
    assert (tmp_path / "p.png").read_bytes()[:4] == b"\x89PNG"
    assert len((tmp_path / "run.csv").read_text().splitlines()) == 1002  # the CSV keeps every sample


@pytest.mark.parametrize("duration", ["1e9", "1e300", "inf", "nan", "-1"])
def test_impossible_durations_are_one_line(capsys, duration):
    code = main(["sim", "paper", "--duration", duration, "--quiet"])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and err.startswith("belt-drive: error: duration:")


def test_step_count_limit(capsys):
    code = main(["sim", "paper", "--duration", "1e6", "--dt", "1e-4", "--quiet"])
    err = capsys.readouterr().err
    assert code == 2 and "steps, more than" in err and err.count("\n") == 1


def test_the_summarys_peak_deflection_is_the_largest_magnitude_for_a_reverse_driven_belt():
    """A drive turning backwards deflects the belt negatively throughout: the summary's peak is the largest
    |relative deflection| (before: the signed max, 0 at the start, printed as "peak 0 rad")."""
    from belt_drive_ros.core.sources import Constant

    whole = simulate(load_scene("paper").with_overrides(duration=0.5, drive=Constant(-5.0)))
    deflection = whole.outputs["relative_deflection"]
    assert deflection.max() <= 0.0 < -deflection.min()
    summary = RunSummary().add(whole)
    assert summary.peak_deflection == -deflection.min()


def test_slipping_windows_of_one_step_are_the_whole_run():
    """stream(bsg_start, window_steps=1): a window whose one step ended on the last window's last sample (an event
    time a rounding past its knot) held no sample and _joined([]) raised; such a window is skipped, and every step
    still advances: the windows put together are the whole run bit for bit."""
    import numpy as np

    from belt_drive_ros.core.simulate import simulate
    from belt_drive_ros.core.stream import stream
    from belt_drive_ros.io.scenes import load_scene

    scene = load_scene("bsg_start").with_overrides(duration=0.5, model="slipping")
    windows = [w for w in stream(scene, window_steps=1) if hasattr(w, "time")]
    whole = simulate(scene)
    assert len(windows) > 1000
    np.testing.assert_array_equal(np.concatenate([w.time for w in windows]), whole.time)
    np.testing.assert_array_equal(np.concatenate([w.states for w in windows]), whole.states)
