"""Hostile variant values in a campaign: a variant outside the plausible ranges a scene file
is held to is that variant's error row, and the batch it shares with good variants still runs them."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
import yaml

from belt_drive_ros.campaign.execute import portable_of, run_batch
from belt_drive_ros.campaign.spec import Campaign, CampaignError
from belt_drive_ros.cli import main


def test_variants_outside_the_plausible_ranges_are_refused_one_by_one(tmp_path, capsys):
    """Before: a grid of params.c = 1e300 / params.I_M = 1e300 (a scene file refuses both: 'outside the plausible
    range') ran the variants; the accuracy guard's eigenvalues of an overflowed matrix raised LinAlgError, which
    failed the whole batch ('batch failed' for the good variant too) and made ``sweep --check`` an internal error
    after three numpy warnings."""
    path = tmp_path / "c.yaml"
    path.write_text(yaml.safe_dump({"name": "c", "scene": "paper", "set": {"duration": 0.05},
                                    "grid": {"params.c": [1.0e300, 1.0], "params.I_M": [1.0e300, 0.01]}}))
    campaign = Campaign.load(path)
    rows = run_batch(portable_of(campaign), campaign.variants()).to_dict("records")
    errors = [r["error"] for r in rows]
    assert [e.split(":")[0] for e in errors] == ["ParameterError"] * 3 + [""], errors
    assert all("plausible range" in e for e in errors[:3]), errors
    assert rows[3]["peak_belt_torque"] > 0 and not math.isnan(rows[3]["final_speed"])
    assert main(["sweep", str(path), "--check", "--quiet"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("belt-drive: error: variant 0: ParameterError: ") and "plausible range" in err[0], err


def test_a_fleet_recording_cut_off_runs_and_says_so_in_its_row_not_on_the_workers_stderr(tmp_path):
    """Before: a recording whose end was cut off ran on its complete chunks with nothing in its row (an intact
    recording's row); the note went to the worker's stderr as a two-line Python warning (lost on a remote cluster)."""
    import struct
    import warnings

    from mcap.writer import Writer

    from belt_drive_ros.campaign.report import summary

    folder = tmp_path / "recs"
    folder.mkdir()
    with open(folder / "a.mcap", "wb") as f:
        writer = Writer(f)
        writer.start(profile="ros2", library="test")
        schema = writer.register_schema(name="std_msgs/msg/Float64", encoding="ros2msg", data=b"float64 data\n")
        channel = writer.register_channel(topic="/drive_torque", message_encoding="cdr", schema_id=schema)
        for k in range(200):
            writer.add_message(channel_id=channel, log_time=10**9 + k * 10**6, publish_time=10**9 + k * 10**6,
                               data=b"\0\1\0\0" + struct.pack("<d", 2.0 + k % 3), sequence=k)
        writer.finish()
    whole = (folder / "a.mcap").read_bytes()
    (folder / "b.mcap").write_bytes(whole[: int(len(whole) * 0.8)])
    path = tmp_path / "fleet.yaml"
    path.write_text(yaml.safe_dump({"name": "f", "scene": "paper", "fleet": {"folder": "recs"}}))
    campaign = Campaign.load(path)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # (nothing escapes as a warning)
        table = run_batch(portable_of(campaign), campaign.variants())
    rows = table.to_dict("records")
    assert [r["recording"] for r in rows] == ["a.mcap", "b.mcap"] and [r["error"] for r in rows] == ["", ""]
    assert rows[0]["warning"] == ""
    assert "b.mcap was not finalized" in rows[1]["warning"] and "using the 200 messages" in rows[1]["warning"]
    assert rows[0]["peak_belt_torque"] == rows[1]["peak_belt_torque"]  # (its chunks hold every message)
    assert "recordings cut off (run on their complete chunks): 1" in summary(table, campaign)


@pytest.mark.parametrize("name, option", [("results.csv", "--csv"), ("results.parquet", "--out"),
                                          ("summary.txt", "--out")])
def test_an_output_file_that_is_a_folder_is_refused_before_the_cluster_starts(tmp_path, capsys, monkeypatch, name,
                                                                               option):
    """Before: ``sweep --csv`` with OUT/results.csv a folder ran the whole campaign, then failed with a bare
    '[Errno 21] Is a directory' naming no option (results.parquet and summary.txt the same way)."""
    from belt_drive_ros.campaign import execute

    def no_cluster(*_args, **_kwargs):
        raise AssertionError("the cluster started")

    monkeypatch.setattr(execute, "_cluster", no_cluster)
    path = tmp_path / "c.yaml"
    path.write_text(yaml.safe_dump({"name": "c", "scene": "paper", "set": {"duration": 0.05},
                                    "grid": {"params.c": [1.0, 2.0]}}))
    out = tmp_path / "out"
    (out / name).mkdir(parents=True)
    assert main(["sweep", str(path), "--out", str(out), "--csv", "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"{out / name}: is a folder, where {option} writes its {name}" in err[0], err
    assert sorted(p.name for p in out.iterdir()) == [name]  # nothing written


def test_a_network_scene_is_refused_as_one_campaigns_do_not_run(tmp_path, capsys):
    """Before: ``scene: fead_i4`` (a shipped belt network scene, run by ``belt-drive sim``) was refused as 'unknown
    scene 'fead_i4': not a file and not a shipped scene', a network scene file as 'scene.belt: unknown key'. The one
    line now says what it is and what a campaign accepts; a drive scene still loads."""
    from importlib import resources

    network_file = tmp_path / "my_network.yaml"
    network_file.write_text((resources.files("belt_drive_ros") / "scenes" / "networks" / "fead_i4.yaml").read_text())
    for scene, what in (("fead_i4", "'fead_i4' is the shipped belt network scene"),
                        ("my_network.yaml", "'my_network.yaml' is a belt network scene file")):
        path = tmp_path / "c.yaml"
        path.write_text(yaml.safe_dump({"name": "c", "scene": scene, "grid": {"params.c": [1.0]}}))
        assert main(["sweep", str(path), "--check", "--quiet"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and f"scene: {what}" in err[0], err
        assert "campaigns run drive scenes only: a shipped one (bsg_start, e_motor_start, paper, truck_compressor)" \
            in err[0], err
    inline = yaml.safe_load(network_file.read_text())
    with pytest.raises(CampaignError, match="^scene: the inline scene is a belt network scene"):
        Campaign.from_mapping({"scene": inline, "grid": {"params.c": [1.0]}})
    assert Campaign.from_mapping({"scene": "paper", "grid": {"params.c": [1.0]}}).size == 1


@pytest.mark.parametrize("case", ["chart is a folder", "chart is the campaign file", "summary is the scene file"])
def test_the_charts_and_inputs_are_checked_before_the_cluster_starts(tmp_path, capsys, monkeypatch, case):
    """Before: ``sweep --plots`` checked none of its charts' paths; OUT/histograms.png a folder failed with a bare
    '[Errno 21] Is a directory' after the whole campaign ran, and a campaign file OUT/histograms.png (or a scene file
    OUT/summary.txt) was replaced by the output. Now each is refused in one line before the cluster starts, and the
    inputs are left as they were."""
    from belt_drive_ros.campaign import execute

    def no_cluster(*_args, **_kwargs):
        raise AssertionError("the cluster started")

    monkeypatch.setattr(execute, "_cluster", no_cluster)
    out = tmp_path / "out"
    out.mkdir()
    spec = {"name": "c", "scene": "paper", "set": {"duration": 0.05}, "grid": {"params.c": [1.0, 2.0]}}
    path = tmp_path / "c.yaml"
    if case == "chart is a folder":
        (out / "histograms.png").mkdir()
        want = f"{out / 'histograms.png'}: is a folder, where --plots writes its histograms.png"
    elif case == "chart is the campaign file":
        path = out / "histograms.png"
        want = f"{out / 'histograms.png'}: is '{path}', which the campaign is read from; --plots would replace it"
    else:
        (out / "summary.txt").write_text("extends: paper\n")
        spec["scene"] = "out/summary.txt"
        want = (f"{out / 'summary.txt'}: is '{out / 'summary.txt'}', which the campaign is read from; "
                "--out would replace")
    path.write_text(yaml.safe_dump(spec))
    before = {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()}
    assert main(["sweep", str(path), "--out", str(out), "--plots", "--force", "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and want in err[0], err
    assert {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()} == before  # nothing written or replaced


def test_a_scene_file_without_a_yaml_suffix_is_found_next_to_the_campaign_file(tmp_path, monkeypatch):
    """`scene: myscene.txt` is relative to the campaign file, as the docs say and as a .yaml name is (before: looked up
    in the working directory, or 'unknown scene'); a shipped scene's name stays the shipped scene."""
    from belt_drive_ros.io.scenes import load_scene

    sub = tmp_path / "sub"
    sub.mkdir()
    for folder, duration in ((sub, 0.2), (tmp_path, 0.3)):
        data = load_scene("paper").to_dict()
        data["duration"] = duration
        (folder / "myscene.txt").write_text(yaml.safe_dump(data))
    (sub / "c.yaml").write_text(yaml.safe_dump({"name": "x", "scene": "myscene.txt", "grid": {"params.c": [1.0]}}))
    monkeypatch.chdir(tmp_path)  # a file of the same name in the working directory: not the one meant
    campaign = Campaign.load(sub / "c.yaml")
    assert campaign.base.duration == 0.2
    (sub / "paper").write_text("not a scene")  # a file named like a shipped scene: the name wins
    (sub / "c.yaml").write_text(yaml.safe_dump({"name": "x", "scene": "paper", "grid": {"params.c": [1.0]}}))
    assert Campaign.load(sub / "c.yaml").base.duration == load_scene("paper").duration




def test_a_campaign_whose_runs_cannot_fit_in_memory_is_refused_up_front(monkeypatch):
    """`set: {duration: 1e6}` on paper: 2e8 steps a variant, each run's step plan (and a single run's trajectory) held
    whole on its worker. Refused before anything runs with what it needs (before: the workers took the machine's
    memory and the sweep ended in an internal error); a long but fitting run passes, and a grid's longest counts."""
    from belt_drive_ros.campaign import limits

    monkeypatch.setattr(limits, "available_memory", lambda: 8 * 2**30)
    huge = Campaign.from_mapping({"scene": "paper", "set": {"duration": 1.0e6},
                                  "monte_carlo": {"samples": 5, "vary": {"params.c": {"normal": 0.1}}}})
    with pytest.raises(CampaignError, match=r"^campaign: a variant's run of 2e\+08 steps \(duration over dt\) needs "
                                            r"~47\.7 GB on each of 1 worker .* more than half the 8 GB"):
        limits.check(huge, 1)
    assert limits.check(Campaign.from_mapping({"scene": "paper", "set": {"duration": 1.0e4},
                                               "grid": {"params.c": [1.0]}}), 1) == 1  # 2e6 steps: ~0.5 GB
    grid = Campaign.from_mapping({"scene": "paper", "grid": {"duration": [1.0, 1.0e6]}})
    with pytest.raises(CampaignError, match="a variant's run of 2e\\+08 steps"):
        limits.check(grid, 2)


def test_the_run_memory_limit_reads_each_variants_own_duration_and_dt(monkeypatch):
    """The longest run is each variant's duration over its dt. A duration drawn by the Monte Carlo (up to 9.5e4 s on
    paper's 5 ms step: ~1.9e7 steps, ~4.9 GB a worker) passed unseen; a grid value the scene refuses anyway (text,
    null: ``float()``'s internal error; 1e300 s, dt 0: the whole campaign refused) is that variant's row."""
    from belt_drive_ros.campaign import limits

    monkeypatch.setattr(limits, "available_memory", lambda: 8 * 2**30)
    drawn = Campaign.from_mapping({"scene": "paper", "monte_carlo": {"samples": 4, "seed": 1, "vary": {
        "duration": {"uniform": [1.0, 1.0e5], "absolute": True}}}})
    longest = float(np.max(drawn.variants()["duration"])) / drawn.base.dt
    assert limits.longest_run_steps(drawn) == pytest.approx(longest) and longest > 1.8e7
    with pytest.raises(CampaignError, match=r"^campaign: a variant's run of 1\.9e\+07 steps"):
        limits.check(drawn, 2)
    step = Campaign.from_mapping({"scene": "paper", "set": {"duration": 100.0}, "monte_carlo": {
        "samples": 3, "vary": {"dt": {"normal": [1.0e-5, 1.0e-6], "absolute": True}}}})
    assert limits.longest_run_steps(step) == pytest.approx(float(np.max(100.0 / step.variants()["dt"])))
    for values, longest in (([1.0, "x"], 200.0), ([None, 2.0, True], 400.0), ([1.0, 1.0e300], 200.0), ([-1.0, 0.5], 100.0)):
        grid = Campaign.from_mapping({"scene": "paper", "grid": {"duration": values}})
        assert limits.longest_run_steps(grid) == pytest.approx(longest)
        assert limits.check(grid, 1) == 1
    grid = Campaign.from_mapping({"scene": "paper", "grid": {"dt": [0.0, 1.0e-3], "duration": [2.0]}})
    assert limits.longest_run_steps(grid) == pytest.approx(2000.0) and limits.check(grid, 1) == 1


def test_the_time_estimate_takes_each_variants_own_steps():
    """The estimate took the base scene's duration over dt for every variant: a grid of dt 1e-5 s on paper (5 s:
    5e5 steps a run) was estimated at 1,000 steps a run, 500x short. It sums each variant's own steps (a variant its
    scene refuses, dt text, counts its fixed cost only)."""
    from belt_drive_ros.campaign import limits

    grid = Campaign.from_mapping({"scene": "paper", "grid": {"dt": [1.0e-5, "x"]}})
    fixed, per_step = limits.VARIANT_SECONDS, limits.STEP_SECONDS
    assert limits.seconds(grid, grid.size, 2) == pytest.approx((2 * fixed + 5.0e5 * per_step) / 2)
    drawn = Campaign.from_mapping({"scene": "paper", "monte_carlo": {"samples": 5, "seed": 3, "vary": {
        "duration": {"uniform": [1.0, 100.0], "absolute": True}}}})
    steps = float(np.sum(drawn.variants()["duration"])) / drawn.base.dt
    assert limits.seconds(drawn, 5, 1) == pytest.approx(5 * fixed + steps * per_step)
    plain = Campaign.from_mapping({"scene": "paper", "grid": {"params.k": [1.0e4, 2.0e4]}})
    assert limits.seconds(plain, 2, 1) == pytest.approx(2 * (fixed + 1000 * per_step))


@pytest.mark.parametrize("scene, key, base", [("paper", "method", "'lawson5'"), ("paper", "model", "'flexible'"),
                                              ("truck_compressor", "drive.harmonics", "[300.0, 90.0]")])
def test_a_draw_of_a_key_the_scene_holds_as_text_or_a_list_is_refused(scene, key, base, capsys):
    """``method: {normal: [1, 1], absolute: true}`` ended in an internal error (``float('lawson5')`` while the variant
    table was drawn); relative, the message said to give absolute: true. Every draw would fail its variant: refused,
    naming the key and its value."""
    for spec in ({"normal": [1.0, 1.0], "absolute": True}, {"uniform": [0.9, 1.1]}):
        with pytest.raises(CampaignError, match=rf"^monte_carlo\.vary\.{key}: draws numbers, and the scene's {key} is "
                                                rf"{re.escape(base)}; vary it by the grid$"):
            Campaign.from_mapping({"scene": scene, "set": {"model": "flexible"},
                                   "monte_carlo": {"samples": 2, "vary": {key: spec}}})


def test_a_relative_tolerance_of_a_zero_base_value_is_refused():
    """``params.b_M: {normal: 0.1}`` with b_M = 0 in the scene drew 0 every time: identical variants, exit 0. Refused;
    an absolute one, or a relative one on a profile field the profiles give a value, is taken."""
    with pytest.raises(CampaignError, match=r"^monte_carlo.vary.params.b_M: a relative tolerance of a base value 0 "
                                            r"varies nothing; give an absolute one"):
        Campaign.from_mapping({"scene": "paper", "monte_carlo": {"samples": 3, "vary": {"params.b_M": {"normal": 0.1}}}})
    ok = Campaign.from_mapping({"scene": "paper", "monte_carlo": {"samples": 3, "vary": {
        "params.b_M": {"normal": [0.01, 0.001], "absolute": True}}}})
    assert ok.variants()["params.b_M"].nunique() == 3


@pytest.mark.parametrize("out, message", [
    ("/proc/belt_drive_x", "--out /proc/belt_drive_x: cannot make the folder (No such file or directory)"),
    ("{tmp}/no/such/x", "--out {tmp}/no/such/x: the folder it goes in, {tmp}/no/such, does not exist"),
])
def test_an_out_folder_that_cannot_be_made_is_named_as_the_option(tmp_path, capsys, out, message):
    """sweep --out /proc/x said '[Errno 2] No such file or directory: '/proc/x'', naming no option."""
    from pathlib import Path

    campaign = Path(__file__).resolve().parents[1] / "examples" / "paper_grid.yaml"
    out = out.format(tmp=tmp_path)
    assert main(["sweep", str(campaign), "--out", out, "--quiet", "--workers", "1"]) == 2
    assert capsys.readouterr().err.strip() == f"belt-drive: error: {message.format(tmp=tmp_path)}"


@pytest.mark.parametrize("grid, message", [
    ({"k": [1.0e4, 2.0e4, 1.0e4]}, r"^grid\.k: 10000\.0 is given twice$"),
    ({"params.c": [0.1, 0.1]}, r"^grid\.params\.c: 0\.1 is given twice$"),
    ({"method": ["etd2", "rk4", "etd2"]}, r"^grid\.method: 'etd2' is given twice$"),
])
def test_a_grid_value_given_twice_is_refused(grid, message):
    """``grid: {k: [1e4, 1e4]}`` ran every variant of that value twice, silently (twice the time, nothing new)."""
    with pytest.raises(CampaignError, match=message):
        Campaign.from_mapping({"scene": "paper", "grid": grid})
    distinct = {key: sorted(set(values), key=values.index) for key, values in grid.items()}
    assert Campaign.from_mapping({"scene": "paper", "grid": distinct}).size == len(next(iter(distinct.values())))


def test_a_value_set_makes_invalid_is_named_as_set_s():
    """``set: {k: -5}`` was refused as 'k: must be > 0 N/m, got -5.0 (in scene.params)': the scene file's own
    error, by the look of it. It is named as what set gave; the scene's own errors are unchanged."""
    with pytest.raises(CampaignError, match=r"^set: k: must be > 0 N/m, got -5\.0"):
        Campaign.from_mapping({"scene": "paper", "set": {"k": -5}})
    with pytest.raises(CampaignError, match=r"^set: "):
        Campaign.from_mapping({"scene": "paper", "set": {"drive.soft_start_time": -1.0}})
    assert Campaign.from_mapping({"scene": "paper", "set": {"k": 2.0e4}}).base.params.k == 2.0e4
