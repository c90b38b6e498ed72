"""Campaigns on a real dask.distributed LocalCluster (worker processes on 127.0.0.1), no mocks.

The reference for every table is a plain loop of single ``simulate`` runs
(:func:`~belt_drive_ros.campaign.execute.loop_of_single_runs`).
"""

from __future__ import annotations

import math
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from distributed import Client, LocalCluster

from belt_drive_ros.campaign.execute import loop_of_single_runs, run_campaign
from belt_drive_ros.campaign.metrics import METRICS
from belt_drive_ros.campaign.spec import Campaign, CampaignError

BAGS = Path(__file__).resolve().parents[1] / "bags"

CAMPAIGN = {
    "name": "paper_small",
    "scene": "paper",
    "set": {"duration": 0.8},
    "grid": {"params.k": [1.6e4, 2.4e4]},
    "monte_carlo": {
        "samples": 12,
        "seed": 5,
        "vary": {"params.I_3": {"uniform": [0.9, 1.1]}, "c": {"normal": 0.1}, "params.F_0": {"normal": [400.0, 10.0], "absolute": True}},
    },
}


@pytest.fixture(scope="module")
def client():
    """Two worker processes on loopback (the campaign tests share them)."""
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1", dashboard_address="127.0.0.1:0") as cluster:
        with Client(cluster) as c:
            yield c


def _campaign(tmp_path: Path, data: dict = CAMPAIGN) -> Campaign:
    path = tmp_path / "campaign.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return Campaign.load(path)


def _metrics_close(a: pd.DataFrame, b: pd.DataFrame, rtol: float) -> None:
    for name in METRICS:
        x, y = a[name].to_numpy(dtype=float), b[name].to_numpy(dtype=float)
        assert np.array_equal(np.isnan(x), np.isnan(y)), name
        ok = ~np.isnan(y)
        assert np.all(np.abs(x[ok] - y[ok]) <= rtol * np.maximum(np.abs(y[ok]), 1e-300) + 1e-12), name


def test_variant_table_is_reproducible_and_follows_the_distributions(tmp_path):
    campaign = _campaign(tmp_path)
    table = campaign.variants()
    assert len(table) == 2 * 12 and list(table["variant"]) == list(range(24))
    assert set(table["params.k"]) == {1.6e4, 2.4e4}
    i3 = table["params.I_3"] / campaign.base.params.I_3
    assert i3.between(0.9, 1.1).all()
    again = _campaign(tmp_path).variants()
    pd.testing.assert_frame_equal(table, again)
    seed = np.random.default_rng(5)  # the documented draw order: key by key in file order
    np.testing.assert_array_equal(table["params.I_3"], campaign.base.params.I_3 * seed.uniform(0.9, 1.1, 24))


def test_cluster_default_and_loop_of_single_runs_give_one_table(tmp_path, client):
    campaign = _campaign(tmp_path)
    on_cluster = run_campaign(campaign, tmp_path / "cluster", client=client, progress=False).table
    by_default = run_campaign(campaign, tmp_path / "default", workers=1, progress=False).table
    loop = pd.DataFrame(loop_of_single_runs(campaign, campaign.variants().to_dict("records")))
    assert len(on_cluster) == len(by_default) == len(loop) == 24
    assert (on_cluster["error"] == "").all() and (on_cluster["ran"] == "ensemble").all()
    pd.testing.assert_frame_equal(on_cluster[list(METRICS)], by_default[list(METRICS)])
    assert list(on_cluster["model"]) == list(loop["model"])
    _metrics_close(on_cluster, loop, rtol=1e-9)
    stored = pd.read_parquet(tmp_path / "cluster" / "results.parquet")
    pd.testing.assert_frame_equal(stored, on_cluster)


def test_interrupted_campaign_resumes_where_it_stopped(tmp_path, client):
    campaign = _campaign(tmp_path)
    out = tmp_path / "run"
    first = run_campaign(campaign, out, client=client, progress=False, batch_size=5, stop_after=2)
    assert first.interrupted and first.computed == 10
    parts = {p.name: p.stat().st_mtime_ns for p in (out / "parts").glob("part-*.parquet")}
    assert len(parts) == 2 and not (out / "results.parquet").exists()
    second = run_campaign(campaign, out, client=client, progress=False, batch_size=5)
    assert not second.interrupted and second.computed == 14
    assert {p.name: p.stat().st_mtime_ns for p in (out / "parts").glob("part-*.parquet") if p.name in parts} == parts
    whole = run_campaign(campaign, tmp_path / "whole", client=client, progress=False, batch_size=5).table
    pd.testing.assert_frame_equal(second.table.drop(columns="seconds"), whole.drop(columns="seconds"))
    edited = dict(CAMPAIGN, name="another")
    with pytest.raises(CampaignError, match="another campaign"):
        run_campaign(_campaign(tmp_path / "x" if (tmp_path / "x").mkdir() is None else tmp_path, edited), out,
                     client=client, progress=False)


def test_an_interrupt_while_a_file_is_written_leaves_no_half_file(tmp_path, client, monkeypatch):
    """SIGINT in the middle of writing a part or results.parquet (a half file written, then KeyboardInterrupt):
    before, the part's ``part-00001.tmp`` stayed in parts/ (``pandas.read_parquet(OUT/parts)``, the documented
    reading of the parts, failed on it) and results.parquet stayed half written. Now neither is there, the parts
    read as a dataset, and the same command completes the campaign."""
    campaign = _campaign(tmp_path)
    out = tmp_path / "run"
    real = pd.DataFrame.to_parquet
    breaks = {"name": "part-00001"}

    def half(frame, target, *args, **kwargs):
        name = os.readlink(f"/proc/self/fd/{target.fileno()}") if hasattr(target, "fileno") else str(target)
        if breaks["name"] in name:
            if hasattr(target, "write"):
                target.write(b"PAR1 half a file")
            else:
                Path(target).write_bytes(b"PAR1 half a file")
            raise KeyboardInterrupt
        return real(frame, target, *args, **kwargs)

    monkeypatch.setattr(pd.DataFrame, "to_parquet", half)
    first = run_campaign(campaign, out, client=client, progress=False, batch_size=8)
    assert first.interrupted
    kept = sorted(p.name for p in (out / "parts").iterdir())  # (the batches finished before part 1, in any order)
    assert set(kept) <= {"part-00000.parquet", "part-00002.parquet"}
    if kept:
        assert len(pd.read_parquet(out / "parts")) == 8 * len(kept)
    breaks["name"] = "results.parquet"
    with pytest.raises(KeyboardInterrupt):
        run_campaign(campaign, out, client=client, progress=False, batch_size=8)
    assert sorted(p.name for p in out.iterdir()) == ["manifest.json", "parts", "variants.parquet"]
    monkeypatch.setattr(pd.DataFrame, "to_parquet", real)
    done = run_campaign(campaign, out, client=client, progress=False, batch_size=8)
    assert not done.interrupted and len(pd.read_parquet(out / "results.parquet")) == 24


def test_a_damaged_part_is_named_and_its_batch_runs_again_once_removed(tmp_path, client):
    """A part file emptied or damaged since it was written (a disk, a hand): the resume ended in an internal error
    naming Arrow's exception. It is named, one line, with what to do; removed, the same command runs its batch."""
    campaign = _campaign(tmp_path)
    out = tmp_path / "run"
    run_campaign(campaign, out, client=client, progress=False, batch_size=8, stop_after=2)
    damaged = sorted((out / "parts").glob("part-*.parquet"))[0]
    damaged.write_bytes(b"")
    with pytest.raises(CampaignError, match=rf"^{damaged}: cannot be read \(.*\); remove it and run the same command "
                                            "again to run its batch again$"):
        run_campaign(campaign, out, client=client, progress=False)
    damaged.unlink()
    done = run_campaign(campaign, out, client=client, progress=False)
    assert not done.interrupted and list(done.table["variant"]) == list(range(24))
    assert (done.table["error"] == "").all()


def test_force_leaves_nothing_of_the_run_before_beside_the_new_results(tmp_path, client):
    """--force in a folder of another run: its results.csv and charts go with it, so no table or chart of the old
    variants sits beside the new results (before: results.parquet had the new rows, results.csv the old ones)."""
    from belt_drive_ros.campaign.report import HISTOGRAMS, SCATTER, plot

    out = tmp_path / "run"
    old = run_campaign(_campaign(tmp_path), out, client=client, progress=False, csv=True)
    plot(old.table, _campaign(tmp_path), out)
    assert (out / "results.csv").exists() and (out / HISTOGRAMS).exists() and (out / SCATTER).exists()
    (tmp_path / "new").mkdir()
    edited = _campaign(tmp_path / "new", dict(CAMPAIGN, name="another"))
    with pytest.raises(CampaignError, match="another campaign"):
        run_campaign(edited, out, client=client, progress=False)
    assert (out / "results.csv").exists()  # refused: nothing touched
    new = run_campaign(edited, out, client=client, progress=False, force=True)
    assert not (out / "results.csv").exists() and not (out / HISTOGRAMS).exists() and not (out / SCATTER).exists()
    pd.testing.assert_frame_equal(pd.read_parquet(out / "results.parquet"), new.table)


def test_a_failing_variant_is_recorded_and_the_campaign_goes_on(tmp_path, client):
    data = {
        "scene": "truck_compressor", "set": {"model": "flexible", "method": "rk4", "dt": 2e-3, "duration": 0.1},
        "grid": {"params.k": [2.0e4, 3.0e6, -5.0]},
    }  # fmt: skip
    campaign = _campaign(tmp_path, data)
    table = run_campaign(campaign, tmp_path / "out", client=client, progress=False).table
    assert list(table["error"] == "") == [True, False, False]
    assert table["error"][1].startswith("UnstableStepError") and "rk4" in table["error"][1]
    assert table["error"][2].startswith("ParameterError") and "k" in table["error"][2]
    assert math.isnan(table["peak_belt_torque"][1]) and table["peak_belt_torque"][0] > 0


def test_fleet_replays_and_compares_against_goldens(tmp_path, client):
    recordings = tmp_path / "recordings"
    recordings.mkdir()
    for k in range(3):
        shutil.copy(BAGS / "engine_idle_torque.mcap", recordings / f"truck_{k}.mcap")
    data = {"scene": str(BAGS / "engine_idle.yaml"), "set": {"model": "flexible"}, "fleet": {"folder": "recordings"}}
    first = run_campaign(_campaign(tmp_path, data), tmp_path / "golden_run", client=client, progress=False)
    assert (first.table["error"] == "").all() and len(first.table) == 3
    golden = tmp_path / "golden_run" / "recordings"
    data["fleet"]["golden"] = str(golden)
    second = run_campaign(_campaign(tmp_path, data), tmp_path / "new_run", client=client, progress=False).table
    assert second["compare_passed"].all() and (second["worst_rel_error"] == 0.0).all()
    # the folder written is what msg-tools compare reads, pairwise by name
    cli = subprocess.run([sys.executable, "-m", "msg_tools", "compare", str(tmp_path / "new_run" / "recordings"), str(golden)],
                         capture_output=True, text=True)
    assert cli.returncode == 0, cli.stdout + cli.stderr


def test_campaign_file_errors_name_the_key(tmp_path):
    for data, key in (
        ({"scene": "paper", "grid": {"params.kk": [1.0]}}, "params.kk"),
        ({"scene": "paper", "monte_carlo": {"samples": 3, "vary": {"k": {"gauss": 0.1}}}}, "monte_carlo.vary.k"),
        ({"scene": "paper", "metrics": ["peak_torque"]}, "metrics"),
        ({"scene": "paper", "bogus": 1}, "bogus"),
    ):
        with pytest.raises(CampaignError, match=key.replace(".", r"\.")):
            _campaign(tmp_path, data)
    # a field no variant's profile or initial state has is refused up front (it failed every variant alike)
    paper_loads = [{"load": {"type": "polynomial", "c0": 0.0, "c1": 0.02}}, {"load": 2.0}]
    for data, message in (
        ({"scene": "paper", "grid": {"drive.bogus": [1.0, 2.0]}}, r"grid\.drive\.bogus: unknown key for a 'motor' drive"),
        ({"scene": "paper", "monte_carlo": {"samples": 3, "vary": {"drive.bogus": {"normal": 0.1}}}},
         r"monte_carlo\.vary\.drive\.bogus: unknown key for a 'motor' drive"),
        ({"scene": "paper", "grid": {"initial_state.omega": [1.0]}}, r"grid\.initial_state\.omega: unknown initial state"),
        ({"scene": "paper", "profiles": paper_loads, "grid": {"load.c1": [0.01, 0.03]}},
         r"grid\.load\.c1: unknown key for a 'constant' load profile; known: value"),
    ):
        with pytest.raises(CampaignError, match=message):
            _campaign(tmp_path, data)
    good = {"scene": "paper", "profiles": paper_loads[:1], "grid": {"load.c1": [0.01], "initial_state.omega_M": [1.0]},
            "monte_carlo": {"samples": 2, "vary": {"drive.stall_torque": {"normal": 0.1}}}}
    assert _campaign(tmp_path, good).size == 2
    path = tmp_path / "bad.yaml"
    path.write_text("scene: paper\ngrid: {params.kk: [1.0]}\n")
    cli = subprocess.run([sys.executable, "-m", "belt_drive_ros.cli", "sweep", str(path)], capture_output=True, text=True)
    assert cli.returncode == 2 and cli.stderr.count("\n") == 1 and "params.kk" in cli.stderr


def test_summary_and_pictures(tmp_path, client):
    data = {"scene": "paper", "set": {"duration": 0.5}, "grid": {"params.k": [1.5e4, 2.0e4, -1.0]},
            "monte_carlo": {"samples": 4, "seed": 2, "vary": {"params.F_0": {"uniform": [0.1, 1.0]}}}}  # fmt: skip
    campaign = _campaign(tmp_path, data)
    done = run_campaign(campaign, tmp_path / "out", client=client, progress=False)
    from belt_drive_ros.campaign.report import plot, summary

    text = summary(done.table, campaign)
    assert "12 runs" in text and "failed: 4" in text and "ParameterError" in text
    assert "accuracy: no verdict per variant" in text  # (a row is no verdict on its step: said where it is read)
    slack = done.table["min_slack_force"].to_numpy(dtype=float)
    beyond = int(np.sum(slack[np.isfinite(slack)] < 0.0))
    assert f"0: {beyond} beyond" in text  # the slack-force limit line counts the runs below 0 N
    written = plot(done.table, campaign, tmp_path / "out")
    assert {p.name for p in written} == {"histograms.png", "metrics_vs_parameters.png"}
    assert all(p.stat().st_size > 10_000 for p in written)


def test_results_parquet_states_the_units_of_its_columns(tmp_path, client):
    """results.parquet held the values without a unit anywhere (the metrics' units were only in summary.txt, the
    parameters' nowhere): its columns' units now ride in the file (``pandas.read_parquet(...).attrs["units"]``)."""
    data = {"scene": "paper", "set": {"duration": 0.2}, "grid": {"params.k": [1.5e4, 2.0e4], "dt": [0.005],
            "initial_state.omega_M": [0.0], "drive.stall_torque": [12.0]}}  # fmt: skip
    run_campaign(_campaign(tmp_path, data), tmp_path / "out", client=client, progress=False)
    units = pd.read_parquet(tmp_path / "out" / "results.parquet").attrs["units"]
    assert units == {"params.k": "N/m", "dt": "s", "initial_state.omega_M": "rad/s", "seconds": "s",
                     **{name: unit for name, (unit, _) in METRICS.items()}}  # fmt: skip
    assert units["peak_belt_torque"] == "N m" and units["min_slack_force"] == "N" and units["final_speed"] == "rad/s"


def test_the_scatter_charts_parameter_ticks_do_not_run_into_one_another(tmp_path, monkeypatch):
    """params.k from 1.5e4 to 2.5e4 on a 3.4-inch panel: five labels of '16000' ran into one another (read as
    '1600018000200002200024000'). Every panel's x tick labels, drawn, keep apart."""
    import matplotlib.pyplot as plt

    from belt_drive_ros.campaign.report import SCATTER, plot

    campaign = _campaign(tmp_path)
    rng = np.random.default_rng(0)
    table = pd.DataFrame({"variant": np.arange(40), "error": [""] * 40, "params.k": np.repeat([1.5e4, 2.5e4], 20),
                          "params.F_0": rng.uniform(300.0, 500.0, 40), "params.I_3": rng.uniform(0.027, 0.033, 40),
                          "params.mu": rng.uniform(0.05, 0.5, 40)})  # fmt: skip
    for name in campaign.metrics:
        table[name] = rng.uniform(0.0, 1.0, 40)
    figures = []
    close = plt.close
    monkeypatch.setattr(plt, "close", lambda fig=None: figures.append(fig))
    written = plot(table, campaign, tmp_path / "charts")
    scatter = figures[[p.name for p in written].index(SCATTER)]
    scatter.canvas.draw()
    renderer = scatter.canvas.get_renderer()
    for ax in scatter.axes:
        boxes = sorted((t.get_window_extent(renderer) for t in ax.get_xticklabels() if t.get_text()), key=lambda b: b.x0)
        # (a space of half a label's height between labels at least: before, 0.5 pixel)
        labels = [t.get_text() for t in ax.get_xticklabels()]
        assert all(b.x0 - a.x1 > 0.5 * a.height for a, b in zip(boxes, boxes[1:])), labels
    for fig in figures:
        close(fig)


def test_local_cluster_workers_keep_blas_single_threaded_and_glibc_malloc_adaptive(monkeypatch):
    """belt-drive sweep's LocalCluster: no MALLOC_TRIM_THRESHOLD_ in the workers (it turns every array over 128 kB
    into a fresh mmap), also when an earlier Dask nanny left it in this process's environment; OPENBLAS_NUM_THREADS=1
    as Dask sets it; the client's Dask config and environment are left as they were."""
    import dask

    from belt_drive_ros.campaign.execute import local_cluster

    monkeypatch.setenv("MALLOC_TRIM_THRESHOLD_", "65536")  # what a default LocalCluster's nanny leaves behind
    before = dask.config.get("distributed.nanny.pre-spawn-environ")
    with local_cluster(1) as cluster, Client(cluster) as c:
        env = next(iter(c.run(lambda: dict(os.environ)).values()))
    assert "MALLOC_TRIM_THRESHOLD_" not in env and env.get("OPENBLAS_NUM_THREADS") == "1"
    assert dask.config.get("distributed.nanny.pre-spawn-environ") == before
    assert os.environ["MALLOC_TRIM_THRESHOLD_"] == "65536"


def test_a_grid_of_bad_methods_gives_one_failing_row_each(tmp_path, client):
    """Mixed types in a grid column (text, a number, null) are tabulated as JSON text: every variant is a row
    with its own error, the table is written (no ArrowTypeError aborting the campaign)."""
    data = {"scene": "paper", "set": {"duration": 0.05}, "grid": {"method": ["nosuch", 7, None, "etd2"]}}
    done = run_campaign(_campaign(tmp_path, data), tmp_path / "out", client=client, progress=False)
    table = pd.read_parquet(tmp_path / "out" / "results.parquet")
    assert list(table["method"]) == ['"nosuch"', "7", "null", '"etd2"']
    assert [e.split(":")[0] for e in table["error"]] == ["SceneError"] * 3 + [""]
    assert "nosuch" in table["error"][0] and "int 7" in table["error"][1] and "None" in table["error"][2]
    assert table["peak_belt_torque"][3] > 0 and len(done.table) == 4


def test_a_fleet_resumed_after_its_folder_changed_is_refused(tmp_path, client):
    """The digest covers the fleet's file list, sizes and times: renaming, removing or adding a recording
    after an interrupted run makes the old parts another campaign's (refused), never reused."""
    recordings = tmp_path / "recordings"
    recordings.mkdir()
    for k in range(3):
        shutil.copy(BAGS / "engine_idle_torque.mcap", recordings / f"truck_{k}.mcap")
    data = {"scene": str(BAGS / "engine_idle.yaml"), "set": {"model": "flexible"}, "fleet": {"folder": "recordings"}}
    out = tmp_path / "run"
    first = run_campaign(_campaign(tmp_path, data), out, client=client, progress=False, batch_size=1, stop_after=1)
    assert first.interrupted and first.computed == 1
    for change in (lambda: (recordings / "truck_2.mcap").rename(recordings / "truck_9.mcap"),
                   lambda: (recordings / "truck_9.mcap").unlink(),
                   lambda: shutil.copy(BAGS / "engine_idle_torque.mcap", recordings / "truck_5.mcap")):
        change()
        with pytest.raises(CampaignError, match="another campaign"):
            run_campaign(_campaign(tmp_path, data), out, client=client, progress=False, batch_size=1)
    done = run_campaign(_campaign(tmp_path, data), out, client=client, progress=False, batch_size=1, force=True)
    assert list(done.table["recording"]) == ["truck_0.mcap", "truck_1.mcap", "truck_5.mcap"]
    assert (done.table["error"] == "").all()


def test_campaigns_beyond_the_machine_are_refused_up_front_with_an_estimate(tmp_path, capsys):
    from belt_drive_ros.cli import main

    path = tmp_path / "c.yaml"
    path.write_text(yaml.safe_dump(CAMPAIGN))
    assert main(["sweep", str(path), "--workers", "1000000", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "1,000,000 worker processes need" in err and "use at most" in err
    big = dict(CAMPAIGN, grid={f"params.{k}": [1.0 + j * 1e-3 for j in range(57)] for k in ("k", "b_M", "I_M", "mu")})
    path.write_text(yaml.safe_dump(big))
    assert main(["sweep", str(path), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "126,672,012 variants" in err and " on " in err and "of tables" in err
    assert not (tmp_path / "o").exists()
    assert main(["sweep", "/dev/zero"]) == 2
    assert "character device; a regular file is needed" in capsys.readouterr().err


def _group(pgid: int) -> list:
    """Processes of the process group ``pgid`` still running (ps: pgid, state, args)."""
    rows = subprocess.run(["ps", "-eo", "pgid=,stat=,args="], capture_output=True, text=True).stdout.splitlines()
    return [r for r in rows if r.split()[0] == str(pgid) and not r.split()[1].startswith("Z")]


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_an_interrupted_sweep_exits_128_plus_the_signal_in_one_line(tmp_path, sig):
    """SIGINT to the whole process group (Ctrl-C in a terminal: the workers get it too) or SIGTERM to the
    command: exit 130 / 143, one line, no worker traceback, no worker left, the parts kept for a resume."""
    data = {"scene": "paper", "monte_carlo": {"samples": 200_000, "seed": 1, "vary": {"params.k": {"normal": 0.05}}}}
    path = tmp_path / "long.yaml"
    path.write_text(yaml.safe_dump(data))
    child = subprocess.Popen(
        [sys.executable, "-m", "belt_drive_ros.cli", "sweep", str(path), "--workers", "2", "--quiet"],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, start_new_session=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )  # fmt: skip
    parts = tmp_path / "long.campaign" / "parts"
    try:
        while not (parts.is_dir() and any(parts.glob("part-*.parquet"))):
            assert child.poll() is None, child.stderr.read()
            time.sleep(0.1)
        if sig == signal.SIGINT:
            os.killpg(child.pid, sig)
        else:
            child.send_signal(sig)
        err = child.communicate(timeout=120)[1]
    finally:
        if child.poll() is None:
            os.killpg(child.pid, signal.SIGKILL)
            child.wait()
    assert child.returncode == 128 + sig, err
    assert err.count("\n") == 1 and err.startswith(f"belt-drive: interrupted by {sig.name}: ") and "Traceback" not in err
    deadline = time.monotonic() + 30.0  # the workers and multiprocessing's resource tracker end on their own
    while (left := _group(child.pid)) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert left == []
    assert any(parts.glob("part-*.parquet"))



@pytest.mark.filterwarnings("error::pytest.PytestUnraisableExceptionWarning")  # printed, under pytest
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_an_interrupt_swallowed_in_a_gc_callback_is_raised_after_the_batch(sig, capfd):
    """Python raises a signal handler's exception in whatever code runs when the signal arrives; inside a
    garbage-collector callback (dask installs one) or a ``__del__`` it is only printed ("Exception ignored
    in ..."), and the sweep went on to the end (CI, once, SIGINT) or printed a traceback above its one
    line (CI, SIGINT and SIGTERM). The campaign loop notes the signal, drops the print, and raises it after
    the batch."""
    import gc

    from belt_drive_ros.campaign.execute import _raise_noted, _signals_noted
    from belt_drive_ros.io.atomic import terminate_raises

    fired, noted = [], []

    def callback(phase, info):
        if phase == "start" and not fired:
            fired.append(1)
            signal.raise_signal(sig)

    with pytest.raises(KeyboardInterrupt) as caught, terminate_raises(), _signals_noted(noted):  # (Terminated is one)
        gc.callbacks.append(callback)
        try:
            gc.collect()  # the handler's exception is printed by the collector, not raised here
        finally:
            gc.callbacks.remove(callback)
        assert fired and noted == [sig]
        _raise_noted(noted)
    assert getattr(caught.value, "signum", signal.SIGINT) == sig
    assert "Exception ignored" not in capfd.readouterr().err
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # handlers restored


@pytest.mark.filterwarnings("error::pytest.PytestUnraisableExceptionWarning")
def test_an_interrupt_during_the_sizing_batches_stops_the_campaign_after_the_part(tmp_path, client, monkeypatch, capfd):
    """The first batches (one per worker, which size the rest) write their parts before the main loop;
    an interrupt printed from a gc callback there was lost (CI, once: ``bench hostile``'s Ctrl-C to
    the sweep's process group printed ``KeyboardInterrupt`` from ``distributed/gc.py`` and the
    sweep went on). It is noted there too and raised after the part is written."""
    import gc

    from belt_drive_ros.campaign import execute

    data = {"name": "sizing", "scene": "paper", "set": {"duration": 0.05},
            "monte_carlo": {"samples": 200, "seed": 1, "vary": {"params.k": {"normal": 0.05}}}}  # fmt: skip
    fired = []
    real = execute.write_part

    def callback(phase, info):
        if phase == "start" and not fired:
            fired.append(1)
            signal.raise_signal(signal.SIGINT)

    def write_part(path, rows):
        real(path, rows)
        if not fired:
            gc.callbacks.append(callback)
            try:
                gc.collect()
            finally:
                gc.callbacks.remove(callback)

    monkeypatch.setattr(execute, "write_part", write_part)
    run = run_campaign(_campaign(tmp_path, data), tmp_path / "out", client=client, progress=False)
    assert fired and run.interrupted and run.signum == signal.SIGINT
    assert run.computed == execute.FIRST_BATCH  # the sizing batch whose part was written, nothing after it
    assert [p.name for p in (tmp_path / "out" / "parts").glob("part-*.parquet")] == ["part-00000.parquet"]
    assert "Exception ignored" not in capfd.readouterr().err
    # resumed with another batch size: the sizing run's part is made again with this run's batches (kept, its 64
    # rows stood for a batch of 100 and the campaign never completed)
    monkeypatch.setattr(execute, "write_part", real)
    again = run_campaign(_campaign(tmp_path, data), tmp_path / "out", client=client, progress=False, batch_size=100)
    assert not again.interrupted and len(again.table) == 200
    assert again.table["variant"].tolist() == list(range(200))


def test_a_sizing_batch_that_breaks_as_a_whole_is_rows_with_the_reason(tmp_path, monkeypatch):
    """The first batches size the rest; one that breaks as a whole (a worker lost, a task cancelled) is recorded as
    its variants' rows with the reason, as any later batch is (before: an 'internal error' that ended the sweep)."""
    from distributed import Client, LocalCluster

    from belt_drive_ros.campaign import execute

    real = execute.run_batch

    def breaks_first(portable, rows, where):
        if int(rows["variant"].iloc[0]) == 0:
            raise RuntimeError("worker lost")
        return real(portable, rows, where)

    monkeypatch.setattr(execute, "run_batch", breaks_first)
    monkeypatch.setattr(execute, "FIRST_BATCH", 4)
    campaign = _campaign(tmp_path)  # 24 variants: two sizing batches of 4, then the rest
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=False, dashboard_address="127.0.0.1:0") as cluster:
        with Client(cluster) as client:  # (threads: the patched run_batch is the one the workers call)
            run = run_campaign(campaign, tmp_path / "out", client=client, progress=False)
    failed = run.table[run.table["error"].str.startswith("batch failed: RuntimeError: worker lost")]
    assert list(failed["variant"]) == [0, 1, 2, 3] and len(run.table) == campaign.size > 8
    assert run.table[~run.table.index.isin(failed.index)]["error"].eq("").all()


def test_the_summary_counts_an_infinite_metric_beyond_its_limit(tmp_path):
    """A belt that lifts off (F_0 = 0) has friction use inf: the summary left such rows out of the range and of the
    limit's count ('max 1.6e6, 3 beyond' where 6 were); a failed run's NaN stays out."""
    from belt_drive_ros.campaign.report import summary

    data = {"scene": "paper", "set": {"duration": 0.5, "model": "flexible"},
            "limits": {"peak_friction_use": 1.0}, "grid": {"params.F_0": [400.0, 0.0]}}  # fmt: skip
    campaign = _campaign(tmp_path, data)
    table = pd.DataFrame({"variant": [0, 1, 2, 3], "ran": ["ensemble"] * 4, "error": ["", "", "", "boom"],
                          "model": ["flexible"] * 4, "single_reason": [""] * 4})
    for name in campaign.metrics:
        table[name] = 0.5
    table["peak_friction_use"] = [0.5, np.inf, 1.6e6, np.nan]
    line = next(row for row in summary(table, campaign).splitlines() if row.strip().startswith("peak_friction_use"))
    assert line.split()[-3:] == ["1:", "2", "beyond"] and "inf" in line, line


def test_the_summary_counts_runs_without_a_value_apart_from_those_within_the_limit(tmp_path):
    """A linear run past the capstan limit has slip_time NaN (slip not modelled); with a limit on slip_time the summary
    said '0 beyond' and nothing of the runs it could not judge. They are counted apart; a failed run's NaN stays out."""
    from belt_drive_ros.campaign.report import summary

    data = {"scene": "paper", "set": {"duration": 0.5, "model": "flexible"}, "limits": {"slip_time": 0.01},
            "grid": {"params.F_0": [400.0, 0.0]}}  # fmt: skip
    campaign = _campaign(tmp_path, data)
    table = pd.DataFrame({"variant": [0, 1, 2, 3], "ran": ["ensemble"] * 4, "error": ["", "", "", "boom"],
                          "model": ["flexible"] * 4, "single_reason": [""] * 4})
    for name in campaign.metrics:
        table[name] = 0.0
    table["slip_time"] = [0.0, np.nan, np.nan, np.nan]
    line = next(row for row in summary(table, campaign).splitlines() if row.strip().startswith("slip_time"))
    assert line.endswith("0.01: 0 beyond, 2 without a value (NaN)"), line
    table["slip_time"] = [np.nan, np.nan, np.nan, np.nan]
    line = next(row for row in summary(table, campaign).splitlines() if row.strip().startswith("slip_time"))
    assert line.endswith("0.01: 0 beyond, 3 without a value (NaN)"), line


def test_the_fleet_chart_draws_a_bar_for_a_recording_equal_to_its_golden(tmp_path):
    """Goldens made by this version (examples/make_fleet.sh) give a worst relative error of 0 for every recording: on
    the log axis no bar was drawn (an empty chart scaled 1 to 10, and matplotlib's 'Data has no positive values'
    warning on the terminal). Each recording now has its bar, green where it passes."""
    import warnings

    from matplotlib.image import imread

    from belt_drive_ros.campaign.report import FLEET_WORST, plot

    campaign = _campaign(tmp_path)
    table = pd.DataFrame({"variant": [0, 1, 2], "recording": ["a.mcap", "b.mcap", "c.mcap"], "error": [""] * 3,
                          "compare_passed": [True] * 3, "worst_signal": ["belt_torque/data"] * 3,
                          "worst_rel_error": [0.0] * 3})  # fmt: skip
    for name in campaign.metrics:
        table[name] = 1.0
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        plot(table, campaign, tmp_path / "charts")
    pixels = imread(tmp_path / "charts" / FLEET_WORST)[..., :3]
    green = (pixels[..., 1] > 0.5) & (pixels[..., 0] < 0.3) & (pixels[..., 2] < 0.3)  # tab:green
    assert np.count_nonzero(np.any(green, axis=1)) > 30  # three bars, each ~15 rows of pixels high


def test_the_fleet_verdict_counts_a_recording_whose_run_failed(tmp_path):
    """A recording that cannot be read (not an MCAP file) fails before it is compared: the summary said 'fleet
    compare: 2 of 2 recordings pass' for a fleet of three."""
    from belt_drive_ros.campaign.report import summary

    campaign = _campaign(tmp_path)
    table = pd.DataFrame({"variant": [0, 1, 2], "recording": ["a.mcap", "b.mcap", "bad.mcap"],
                          "ran": ["single", "single", "none"], "model": ["flexible", "flexible", ""],
                          "single_reason": [""] * 3, "error": ["", "", "BagReadError: bad.mcap: not an MCAP file"],
                          "compare_passed": [True, True, None], "worst_signal": ["x", "x", None],
                          "worst_rel_error": [0.0, 0.0, np.nan]})  # fmt: skip
    for name in campaign.metrics:
        table[name] = [1.0, 1.0, np.nan]
    assert "  fleet compare: 2 of 3 recordings pass (1 not compared: the run failed)" in summary(table, campaign)


def test_the_summary_counts_the_runs_that_slipped_at_the_friction_limit(tmp_path):
    """model: auto sends a variant past the capstan limit to the slipping model, whose friction use stops at 1 while
    the belt slides: with the default limit 1 the summary said '1: 0 beyond' for a campaign whose runs slipped. The
    runs the slipping model held at the limit are counted beside it."""
    from belt_drive_ros.campaign.report import summary

    campaign = _campaign(tmp_path, {"scene": "paper", "set": {"duration": 0.5}, "grid": {"params.F_0": [30.0, 400.0]}})
    table = pd.DataFrame({"variant": [0, 1, 2, 3], "ran": ["single", "single", "ensemble", "ensemble"],
                          "error": [""] * 4, "model": ["slipping", "slipping", "flexible", "flexible"],
                          "single_reason": [""] * 4})  # fmt: skip
    for name in campaign.metrics:
        table[name] = 0.5
    table["peak_friction_use"] = [1.0, 0.9, 0.4, 1.2]
    line = next(row for row in summary(table, campaign).splitlines() if row.strip().startswith("peak_friction_use"))
    assert line.endswith("1: 1 beyond, 1 slipped (the slipping model's use stops at 1)"), line
    table["peak_friction_use"] = [1.0, 1.0, 0.4, 0.5]
    line = next(row for row in summary(table, campaign).splitlines() if row.strip().startswith("peak_friction_use"))
    assert line.endswith("1: 0 beyond, 2 slipped (the slipping model's use stops at 1)"), line


def test_a_relative_draw_on_a_profile_field_is_relative_to_each_profiles_value(tmp_path):
    """Two motor profiles (8 and 16 N m stall) and drive.stall_torque: {normal: 0.01}: every draw scaled the base
    scene's 12 N m and replaced the profile's value, so both profiles drew about 12. Each draws about its own now;
    a profile without the field keeps the base scene's, and the factors (the rng stream) are the same."""
    motor = {"type": "motor", "no_load_speed": 160.0, "soft_start_time": 0.02}
    data = {"scene": "paper", "set": {"duration": 0.2},
            "profiles": [{"drive": {**motor, "stall_torque": 8.0}}, {"drive": {**motor, "stall_torque": 16.0}}],
            "monte_carlo": {"samples": 50, "seed": 1, "vary": {"drive.stall_torque": {"normal": 0.01}}}}  # fmt: skip
    campaign = _campaign(tmp_path, data)
    table = campaign.variants()
    for j, own in ((0, 8.0), (1, 16.0)):
        drawn = table.loc[table["profile"] == j, "drive.stall_torque"].to_numpy()
        assert np.all(np.abs(drawn / own - 1.0) < 0.05) and np.std(drawn / own) > 1e-3
        scene = campaign.scene_of(table[table["profile"] == j].iloc[0].to_dict())
        assert scene.drive.stall_torque == drawn[0]
    factors = table["drive.stall_torque"].to_numpy() / np.where(table["profile"] == 0, 8.0, 16.0)
    base = _campaign(tmp_path, {**data, "profiles": [{"drive": dict(motor)}, {"drive": dict(motor)}]}).variants()
    np.testing.assert_allclose(base["drive.stall_torque"].to_numpy() / 12.0, factors, rtol=1e-15)
