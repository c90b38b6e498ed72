"""``belt-drive bench``: the command writes every CSV, PNG and the summary (quick configuration)."""

from __future__ import annotations

import subprocess
import sys

import pytest

from belt_drive_ros.benchmarks.common import read_csv
from belt_drive_ros.cli import build_parser, main


def test_bench_all_quick_writes_every_file(tmp_path, monkeypatch):
    from belt_drive_ros.commands import bench

    node_calls = []
    monkeypatch.setattr(bench, "_run_node", lambda out, quick: node_calls.append((out, quick)) or 0)
    monkeypatch.setattr(bench, "_single_threaded_blas", lambda: "BLAS as configured (test)")
    status = main(["bench", "all", "--quick", "--quiet", "--out", str(tmp_path)])
    assert status == 0
    assert node_calls == [(tmp_path, True)]  # 'all' includes the node's figures
    for name in ("workprecision", "stability_map", "fidelity", "versus_scipy", "versus_matched", "realtime"):
        rows = read_csv(tmp_path / f"{name}.csv")
        assert rows, name
    for name in ("workprecision", "stability_map", "fidelity", "versus_scipy"):
        png = tmp_path / f"{name}.png"
        assert png.read_bytes()[:4] == b"\x89PNG" and png.stat().st_size < 300_000
    summary = (tmp_path / "summary.md").read_text()
    for heading in ("x real time", "Matched accuracy", "Work-precision", "Stability boundary", "Fidelity"):
        assert heading in summary
    # no NaN is ever written: unstable points carry a status instead
    for row in read_csv(tmp_path / "workprecision.csv"):
        assert "nan" not in {str(v).lower() for v in row.values()}


def test_bench_node_dispatches_to_the_node_module(tmp_path, monkeypatch):
    import types

    from belt_drive_ros.commands import bench

    seen = []
    fake = types.SimpleNamespace(main=lambda argv: seen.append(argv) or 0)
    monkeypatch.setitem(sys.modules, "belt_drive_ros.benchmarks.node", fake)
    monkeypatch.setattr(bench, "_single_threaded_blas", lambda: "BLAS as configured (test)")
    assert main(["bench", "node", "--out", str(tmp_path)]) == 0
    assert main(["bench", "node", "--out", str(tmp_path), "--duration", "12", "--floor", "-p", "model:=rigid"]) == 0
    assert seen == [["--out", str(tmp_path), "--duration", "30.0"],
                    ["--out", str(tmp_path), "--duration", "12.0", "--floor", "-p", "model:=rigid"]]


def test_bench_node_runs_the_scene_asked_for_by_option_or_parameter(tmp_path, monkeypatch):
    """``--scene X`` and ``-p scene:=X`` both name the node's scene (the node's positional scene, which the
    bench passes, used to win over ``-p scene:=``: the bench ran paper); two different ones are refused."""
    import types

    from belt_drive_ros.benchmarks.node import parse_args, scene_of
    from belt_drive_ros.commands import bench

    assert scene_of(None, []) == ("paper", [])
    assert scene_of(None, ["scene:=fead_i4", "model:=rigid"]) == ("fead_i4", ["model:=rigid"])
    assert scene_of("fead_i4", ["scene:=fead_i4"]) == ("fead_i4", [])
    with pytest.raises(ValueError, match="different scenes"):
        scene_of("paper", ["scene:=fead_i4"])
    with pytest.raises(ValueError, match="different scenes"):
        scene_of(None, ["scene:=paper", "scene:=fead_i4"])
    args = parse_args(["-p", "scene:=fead_i4", "-p", "tick_lead:=0.0004"])
    assert args.scene == "fead_i4" and args.param == ["tick_lead:=0.0004"]
    with pytest.raises(SystemExit):
        parse_args(["--scene", "paper", "-p", "scene:=fead_i4"])
    seen = []
    monkeypatch.setitem(sys.modules, "belt_drive_ros.benchmarks.node", types.SimpleNamespace(main=lambda a: seen.append(a) or 0))
    monkeypatch.setattr(bench, "_single_threaded_blas", lambda: "BLAS as configured (test)")
    assert main(["bench", "node", "--out", str(tmp_path), "--scene", "fead_i4"]) == 0
    assert seen == [["--out", str(tmp_path), "--duration", "30.0", "--scene", "fead_i4"]]


def test_bench_parser_lists_the_studies():
    parser = build_parser()
    args = parser.parse_args(["bench", "versus", "--out", "x", "--quick"])
    assert args.study == "versus" and args.quick
    with pytest.raises(SystemExit):
        parser.parse_args(["bench", "nonsense"])


def test_bench_help_names_the_campaign_study_s_own_variant_count():
    """The help's line for 'campaign' states the Monte Carlo it runs by default (it said 10,000, the 1-vs-2-worker
    part's count, where the study runs 100,000 and --samples says so)."""
    from belt_drive_ros.benchmarks import campaign
    from belt_drive_ros.commands import bench

    line = next(line for line in bench.EPILOG.splitlines() if line.startswith("  campaign "))
    assert f"{campaign.SAMPLES:,}-variant Monte Carlo" in line


def test_bench_out_help_says_which_studies_write_nothing(tmp_path, monkeypatch, capsys):
    """``--out``'s help said node-tick and replay write their tables with --out; they print their figures and write
    nothing (their runs take no folder): the help says so, and such a run leaves --out untouched."""
    from belt_drive_ros.benchmarks import node_tick, replay

    with pytest.raises(SystemExit):
        build_parser().parse_args(["bench", "--help"])
    help_text = " ".join(capsys.readouterr().out.split())
    assert "node-tick and replay print their figures and write nothing" in help_text
    monkeypatch.setattr(replay, "main", lambda minutes, baseline=None: 0)
    monkeypatch.setattr(node_tick, "main", lambda quick=False, baseline=None: 0)
    for study in ("replay", "node-tick"):
        out = tmp_path / study
        assert main(["bench", study, "--out", str(out)]) == 0
        assert not out.exists()


def test_bench_command_does_not_import_rclpy_or_numpy_at_import():
    code = (
        "import sys; import belt_drive_ros.commands.bench, belt_drive_ros.benchmarks; "
        "print('rclpy' in sys.modules, 'numpy' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    assert out == ["False", "False"]


@pytest.mark.ros
def test_bench_soak_prints_rss_growth_rates_and_losses(tmp_path):
    """``bench soak`` runs the recording node (a child process) and reports its figures and the recording's."""
    import re

    proc = subprocess.run(
        [sys.executable, "-m", "belt_drive_ros.cli", "bench", "soak", "--seconds", "3", "--quick", "--out", str(tmp_path)],
        capture_output=True, text=True, timeout=180,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    text = proc.stdout
    assert "node exit 0" in text and "Traceback" not in proc.stderr
    assert re.search(r"RSS growth +[+-]\d+\.\d KiB/min .*MiB\)", text)
    rates = re.search(r"rate per 1 s window +min ([\d.]+) Hz, median ([\d.]+) Hz, max ([\d.]+) Hz \((\d) windows", text)
    assert rates and float(rates[1]) <= float(rates[2]) <= float(rates[3]) and int(rates[4]) == 3
    lost = re.search(r"messages lost +(\d+) of the node's (\d+) ticks .* the recording holds all (\d+) \((\d+) in 1 file", text)
    assert lost and int(lost[1]) <= int(lost[2]) == int(lost[3]) <= int(lost[4]) and int(lost[2]) > 0
    assert (tmp_path / "soak.md").read_text().count("RSS growth") == 1


@pytest.mark.ros
def test_bench_hostile_quick_writes_the_table(tmp_path, ros_domain_id):
    """``bench hostile --quick`` runs a sample of every category through the real entry points
    and writes the table (CSV and markdown): the counts add up, nothing crashed or hung, and the
    only silent wrong answers allowed are ``msg-tools info``'s (it reads the summary, not every
    chunk: a flipped bit inside a chunk is "complete" to it; export and compare refuse the file)."""
    import csv

    from belt_drive_ros.benchmarks import hostile

    argv = ["--quick", "--out", str(tmp_path), "--domain-id", str(ros_domain_id)]
    status = hostile.main(argv)
    rows = {r["category"]: r for r in csv.DictReader((tmp_path / "hostile.csv").open())}
    assert set(rows) == {"scene file", "cli", "mcap export", "mcap info", "mcap compare", "campaign file", "bag folder",
                         "campaign run", "node torque", "node parameter", "node reset flood",
                         "node setparameters", "fifo read paths", "truncated files"}  # issue 24: the campaign, bag and last three
    for category, row in rows.items():
        counts = {k: int(v) for k, v in row.items() if k != "category"}
        assert counts["inputs tried"] == sum(counts[o] for o in hostile.OUTCOMES) > 0, category
        assert counts["crash"] == counts["hang"] == 0, (category, (tmp_path / "hostile_details.txt").read_text())
        if category != "mcap info":
            assert counts["silent wrong"] == 0, (category, (tmp_path / "hostile_details.txt").read_text())
    assert int(rows["scene file"]["clean error"]) > 20 and int(rows["node torque"]["clean error"]) > 0
    bad = sum(int(r["silent wrong"]) + int(r["crash"]) + int(r["hang"]) for r in rows.values())
    assert status == (1 if bad else 0)
    assert "| category | inputs tried |" in (tmp_path / "hostile.md").read_text()


@pytest.mark.ros
def test_bench_node_floor_measures_the_node_and_a_model_free_twin_the_same_way(tmp_path):
    """``bench node --floor``: two children measured one after the other by the same probe; the
    floor publishes the node's joint_states on its tick grid and echoes drive_torque as the node does."""
    import csv

    proc = subprocess.run(
        [sys.executable, "-m", "belt_drive_ros.cli", "bench", "node", "--quick", "--floor", "--out", str(tmp_path)],
        capture_output=True, text=True, timeout=240,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "node against its floor" in proc.stdout and "machine steal" in proc.stdout
    rows = list(csv.DictReader((tmp_path / "node.csv").open()))
    assert [r["process"] for r in rows] == ["node", "floor (rclpy + DDS, no model)"]
    for r in rows:
        assert float(r["rate_received_hz"]) > 0 and int(r["latency_samples"]) > 0, r  # stamps decoded, torque echoed
        assert float(r["period_error_p50_ms"]) == 0.0, r  # stamps on the 1 ms grid
        assert 0.0 <= float(r["steal_percent"]) <= 100.0
    # the node's own publish periods come from its /diagnostics (the floor publishes none)
    assert 0.0 <= float(rows[0]["own_period_error_p50_ms"]) <= float(rows[0]["own_period_error_p99_ms"])
    assert rows[1]["own_period_error_p99_ms"] == "nan"


@pytest.mark.ros
def test_bench_node_runs_a_network_scene_given_as_a_parameter_beside_its_floor(tmp_path):
    """``bench node -p scene:=fead_i4 --floor`` runs the network node (the scene it reports in /diagnostics is
    printed and written) and a floor publishing the network's joint_states (the torque echoed as its first
    effort, as the node's crank)."""
    import csv

    proc = subprocess.run(
        [sys.executable, "-m", "belt_drive_ros.cli", "bench", "node", "--quick", "--floor", "-p", "scene:=fead_i4",
         "--out", str(tmp_path)], capture_output=True, text=True, timeout=240,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "  scene                  fead_i4\n" in proc.stdout and "MISMATCH" not in proc.stdout
    assert "- (joint_states of fead_i4)" in proc.stdout and "[target <= 5:" in proc.stdout
    rows = list(csv.DictReader((tmp_path / "node.csv").open()))
    assert rows[0]["scene"] == "fead_i4" and rows[0]["tick_compute_p50_us"] != "nan"
    for r in rows:
        assert float(r["rate_received_hz"]) > 0 and int(r["latency_samples"]) > 0, r


def test_bench_node_reads_the_nodes_own_period_error_from_its_latest_diagnostics():
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

    from belt_drive_ros.benchmarks.node import _own_period_error

    def array(name, p99):
        values = [KeyValue(key=f"period_error_ms_{q}", value=v) for q, v in (("p50", "0.01"), ("p99", p99), ("max", "2.5"))]
        return DiagnosticArray(status=[DiagnosticStatus(name="belt_drive: input"),
                                       DiagnosticStatus(name=name, values=values)])

    assert _own_period_error([array("belt_drive: simulation", "0.9"), array("belt_drive: simulation", "0.12")]) == (
        0.01, 0.12, 2.5)
    assert all(v != v for v in _own_period_error([array("other: thing", "0.1")]))  # NaN: no node diagnostics


def test_bench_replay_prints_the_split_of_a_torque_bag_replayed_to_mcap(tmp_path, capsys):
    """``bench replay``: the bag replayed through sim's streamed path in a child process, split into reading,
    simulation and writing, with the peak memory and its growth per sample."""
    assert main(["bench", "replay", "--minutes", "0.5", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    for label in ("read the bag", "simulation", "writing", "main thread CPU", "process CPU", "peak RSS",
                  "B per bag sample"):
        assert label in out, label
    assert "210,008 messages" in out  # 30,001 samples x 7 topics (drive, joint_states, /tf, 4 outputs) + the URDF

def test_bench_baseline_must_be_a_checkout_and_a_study_that_uses_it(tmp_path, capsys):
    """``--baseline DIR`` that is no checkout would let the child processes import this tree's package and
    print this tree against itself as a ratio of ~1: refused in one line before anything runs."""
    assert main(["bench", "kernel", "--quick", "--baseline", str(tmp_path), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not a checkout of belt_drive_ros" in err[0] and str(tmp_path) in err[0]
    assert not (tmp_path / "o").exists()  # refused before the output folder is made
    assert main(["bench", "workprecision", "--baseline", str(tmp_path), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "'bench workprecision'" in err[0]


def _fake_checkout(root, core_files: dict) -> None:
    """A checkout of ``belt_drive_ros`` at ``root`` whose ``core`` holds only ``core_files`` (name: source)."""
    core = root / "belt_drive_ros" / "core"
    core.mkdir(parents=True)
    (root / "belt_drive_ros" / "__init__.py").write_text("")
    (core / "__init__.py").write_text("")
    for name, text in core_files.items():
        (core / name).write_text(text)


def test_bench_kernel_baseline_runs_the_baseline_trees_code(tmp_path, monkeypatch):
    """``_simulate_side_by_side`` times this tree and the baseline checkout each in its own process: a fake
    checkout whose simulate() burns 50 ms of CPU shows up in the baseline's column only."""
    from belt_drive_ros.benchmarks import kernel

    _fake_checkout(tmp_path, {
        "scene.py": "import types\ndef load_scene(name):\n    return types.SimpleNamespace(duration=7.0)\n",
        "simulate.py": "import time\ndef simulate(scene):\n    end = time.process_time() + 0.05\n"
                       "    while time.process_time() < end:\n        pass\n",
    })  # fmt: skip
    monkeypatch.setattr(kernel, "SCENES", ("paper",))
    rows = kernel._simulate_side_by_side(tmp_path, repeats=1, rounds=1)
    cpu, old, duration = rows["paper"]
    assert set(rows) == {"paper"} and duration == 5.0  # this tree's scene
    assert 0.0 < cpu < 0.05 <= old < 1.0  # the fake's 50 ms, not this tree's few ms


def test_bench_compile_quick_times_each_build_from_an_empty_cache_beside_a_baseline(tmp_path, capsys):
    """``bench compile --quick``: the torque dispatcher's entries built in a child process from an empty numba cache
    (each build named with its time, the wall time; the tree's own cache untouched), and ``--baseline``'s code built
    the same way in a child of that checkout: a fake checkout whose profile compiles one function of its own shows
    that function in the baseline's rows only."""
    from pathlib import Path

    import belt_drive_ros

    pycache = Path(belt_drive_ros.__file__).parent / "core" / "__pycache__"
    before = {p.name: p.stat().st_mtime_ns for p in pycache.glob("*.nb*")}
    fake = tmp_path / "old"
    _fake_checkout(fake, {
        "warm.py": "",
        "sources.py": "import numba\n@numba.njit\ndef baseline_only(t):\n    return t + 1.0\n"
                      "class Engine:\n    def torque(self, t, angle, speed):\n        return baseline_only(0.5)\n",
    })  # fmt: skip
    assert main(["bench", "compile", "--quick", "--baseline", str(fake), "--out", str(tmp_path / "o")]) == 0
    out = capsys.readouterr().out
    rows = read_csv(tmp_path / "o" / "compile.csv")
    mine = {r["what"]: float(r["seconds"]) for r in rows if r["tree"] == "this tree"}
    theirs = {r["what"]: float(r["seconds"]) for r in rows if r["tree"] != "this tree"}
    assert mine["kernel_profiles.profile_torque"] > 0.0 and mine["kernel_profiles.profile_torque_array"] > 0.0
    assert mine["wall, one process"] >= mine["kernel_profiles.profile_torque_array"]
    assert "sources.baseline_only" in theirs and "sources.baseline_only" not in mine
    assert not any(name.startswith("kernel_profiles.") for name in theirs)
    assert "kernel_profiles.profile_torque_array" in out and f"baseline {fake}" in out
    assert {p.name: p.stat().st_mtime_ns for p in pycache.glob("*.nb*")} == before
