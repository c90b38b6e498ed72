"""An output never replaces an input of the same run, --force or not: a fleet sweep's runs are not written over the
recordings they replay or the goldens they are compared with, ``sim --out`` not over its torque bag, recording or
scene, ``msg-tools export --out`` not over the bag it reads; one error line naming both, exit 2, nothing touched."""

from __future__ import annotations

import hashlib
import re
import struct

import pytest
import yaml

from belt_drive_ros.campaign.execute import run_campaign
from belt_drive_ros.campaign.spec import Campaign, CampaignError
from belt_drive_ros.cli import main


def _torque_bag(path, n=50):
    from mcap.writer import Writer

    with open(path, "wb") as f:
        writer = Writer(f)
        writer.start(profile="ros2", library="test")
        schema = writer.register_schema(name="std_msgs/msg/Float64", encoding="ros2msg", data=b"float64 data\n")
        channel = writer.register_channel(topic="/drive_torque", message_encoding="cdr", schema_id=schema)
        for k in range(n):
            t = 10**9 + k * 10**6
            writer.add_message(channel_id=channel, log_time=t, publish_time=t, data=b"\0\1\0\0" + struct.pack("<d", 2.0 + k % 3),
                               sequence=k)
        writer.finish()
    return path


def _digests(folder):
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(folder.rglob("*")) if p.is_file()}


def _fleet(tmp_path, golden: str | None):
    recordings = tmp_path / "fleet" / "recordings"
    recordings.mkdir(parents=True)
    for name in ("a.mcap", "b.mcap"):
        _torque_bag(recordings / name)
    spec = {"name": "f", "scene": "paper", "fleet": {"folder": "fleet/recordings"}}
    if golden:
        (tmp_path / golden).mkdir(parents=True)
        for name in ("a.mcap", "b.mcap"):
            _torque_bag(tmp_path / golden / name, n=60)
        spec["fleet"]["golden"] = golden
    path = tmp_path / "fleet.yaml"
    path.write_text(yaml.safe_dump(spec))
    return path


@pytest.mark.parametrize("which", ["fleet.folder", "fleet.golden"])
def test_a_fleet_sweep_does_not_write_its_runs_over_its_recordings_or_goldens(which, tmp_path, capsys):
    """Before: --out fleet (the folder holding recordings/) wrote each run over the recording it replayed, exit 0; with
    the goldens in OUT/recordings each run replaced its golden and every comparison passed against itself."""
    if which == "fleet.folder":
        path, out = _fleet(tmp_path, None), tmp_path / "fleet"
    else:
        path, out = _fleet(tmp_path, "runs/recordings"), tmp_path / "runs"
    before = _digests(tmp_path)
    campaign = Campaign.load(path)
    with pytest.raises(CampaignError, match=rf"its recordings/ folder, where the replayed runs go, is {which} .*use another --out"):
        run_campaign(campaign, out, client=object(), force=True)  # (refused before the client is used)
    assert main(["sweep", str(path), "--out", str(out), "--quiet", "--force"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and re.search(f"^belt-drive: error: .*is {which} .*would overwrite", err[0]), err
    assert _digests(tmp_path) == before


def test_a_sweep_out_that_is_a_file_is_refused_before_the_cluster_starts(tmp_path, capsys):
    """Before: '[Errno 20] Not a directory: OUT/parts', after a local cluster had started."""
    path = tmp_path / "c.yaml"
    path.write_text(yaml.safe_dump({"scene": "paper", "grid": {"params.k": [2.0e4]}}))
    with pytest.raises(CampaignError, match="c.yaml: exists and is not a folder; --out names the folder"):
        run_campaign(Campaign.load(path), path, client=object())
    assert main(["sweep", str(path), "--out", str(path), "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "exists and is not a folder" in err[0], err


def _sim(argv, capsys):
    status = main([str(a) for a in argv])
    return status, capsys.readouterr().err.strip().splitlines()


def test_sim_out_or_plot_never_replaces_the_torque_bag_recording_or_bag_folder_it_reads(tmp_path, capsys):
    """Before: 'sim SCENE --torque-bag B --out B --force' replaced the bag by the run (whose scene record then names a
    bag that no longer exists), as did 'sim REC --out REC --force', a bag folder re-simulated into itself and a
    network recording re-simulated over itself; --plot B.png over a bag named .png."""
    bag = _torque_bag(tmp_path / "bag.mcap")
    png = _torque_bag(tmp_path / "bag.png")
    assert _sim(["sim", "paper", "--torque-bag", bag, "--quiet", "--out", tmp_path / "rec.mcap"], capsys)[0] == 0
    assert _sim(["sim", "paper", "--torque-bag", bag, "--quiet", "--out", tmp_path / "F", "--bag-folder"], capsys)[0] == 0
    assert _sim(["sim", "fead_i4", "--duration", "0.02", "--quiet", "--out", tmp_path / "net.mcap"], capsys)[0] == 0
    link = tmp_path / "link.mcap"
    link.symlink_to(bag)
    before = _digests(tmp_path)
    for argv, replaced in (
        (["sim", "paper", "--torque-bag", bag, "--out", bag], bag),
        (["sim", "paper", "--torque-bag", link, "--out", bag], link),  # (another name of the same file)
        (["sim", "paper", "--torque-bag", png, "--plot", png], png),
        (["sim", tmp_path / "rec.mcap", "--out", tmp_path / "rec.mcap"], tmp_path / "rec.mcap"),
        (["sim", tmp_path / "rec.mcap", "--torque-bag", bag, "--out", bag], bag),
        (["sim", tmp_path / "F", "--out", tmp_path / "F", "--bag-folder"], tmp_path / "F"),
        (["sim", "paper", "--torque-bag", tmp_path / "F" / "F_0.mcap", "--out", tmp_path / "F", "--bag-folder"],
         tmp_path / "F" / "F_0.mcap"),  # (a bag inside the folder --out replaces)
        (["sim", tmp_path / "net.mcap", "--out", tmp_path / "net.mcap"], tmp_path / "net.mcap"),
    ):
        status, err = _sim([*argv, "--force", "--quiet"], capsys)
        assert status == 2 and len(err) == 1, (argv, err)
        assert re.search(rf"^belt-drive: error: --(out|plot) .*: would replace {re.escape(str(replaced))}, which this run reads",
                         err[0]), err
    assert _digests(tmp_path) == before
    status, err = _sim(["sim", "paper", "--torque-bag", tmp_path / "F", "--out", tmp_path / "F" / "x.csv", "--quiet"], capsys)
    assert status == 0 and (tmp_path / "F" / "x.csv").exists()  # (a new file beside a bag replaces nothing)


@pytest.mark.parametrize("verb", ["export", "plot"])
def test_msg_tools_out_never_replaces_the_bag_it_reads(verb, tmp_path, capsys):
    """Before: 'msg-tools export B --out B --force' replaced the bag by its CSV (plot: a bag named .png by the PNG)."""
    from msg_tools.cli import main as msg_tools

    bag = _torque_bag(tmp_path / ("bag.mcap" if verb == "export" else "bag.png"))
    before = _digests(tmp_path)
    argv = [verb, str(bag), "--out", str(bag), "--force"] + (["--topic", "/drive_torque"] if verb == "export" else [])
    assert msg_tools(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"msg-tools: error: cannot write {bag}: it is the bag {bag} being read; write elsewhere"], err
    assert _digests(tmp_path) == before


@pytest.mark.parametrize("how", ["in memory, the write fails", "streamed, interrupted"])
def test_sim_bag_folder_force_keeps_the_old_bag_until_the_new_one_is_whole(how, tmp_path, capsys, monkeypatch):
    """Before: 'sim ... --out K --bag-folder --force' over an existing bag folder removed the old bag when it began to
    write, so a run interrupted (Ctrl-C) or failing (disk full) left neither bag; a file output keeps the old file."""
    from belt_drive_ros.commands import sim
    from belt_drive_ros.io import recording, run_writers

    folder = tmp_path / "K"
    assert _sim(["sim", "paper", "--duration", "0.05", "--quiet", "--out", folder, "--bag-folder"], capsys)[0] == 0
    before = _digests(tmp_path)
    if how.startswith("in memory"):
        real = recording.write_result_mcap

        def fails(*args, **kwargs):
            real(*args, **kwargs)  # (the new bag written whole, then the disk is full)
            raise OSError(28, "No space left on device")

        monkeypatch.setattr(recording, "write_result_mcap", fails)
    else:
        monkeypatch.setattr(sim, "STREAM_ABOVE", 10)
        real_add = run_writers.McapWindows.add

        def interrupted(self, window):
            real_add(self, window)
            raise KeyboardInterrupt

        monkeypatch.setattr(run_writers.McapWindows, "add", interrupted)
    status, err = _sim(["sim", "paper", "--duration", "0.2", "--quiet", "--out", folder, "--bag-folder", "--force"], capsys)
    assert status != 0 and len(err) == 1, err
    assert _digests(tmp_path) == before and sorted(p.name for p in tmp_path.iterdir()) == ["K"]  # (no hidden copy left)
    monkeypatch.undo()
    assert _sim(["sim", "paper", "--duration", "0.2", "--quiet", "--out", folder, "--bag-folder", "--force"], capsys)[0] == 0
    assert _digests(tmp_path) != before and sorted(p.name for p in tmp_path.iterdir()) == ["K"]


@pytest.mark.parametrize("argv", [["urdf", "{yaml}", "--out", "{yaml}"], ["urdf", "{png}", "--png", "{png}"],
                                  ["modes", "{net}", "--campbell", "{net}"], ["modes", "{net}", "--runup", "{net}"]])
def test_urdf_and_modes_outputs_never_replace_the_scene_file(argv, tmp_path, capsys):
    """Before: 'urdf SCENE.yaml --out SCENE.yaml --force' replaced the scene by its URDF (--png: a scene named .png by
    the picture; modes' charts likewise a network scene named .png)."""
    from importlib import resources

    scenes = resources.files("belt_drive_ros") / "scenes"
    paths = {"yaml": tmp_path / "s.yaml", "png": tmp_path / "s.png", "net": tmp_path / "n.png"}
    paths["yaml"].write_text((scenes / "paper.yaml").read_text())
    paths["png"].write_text((scenes / "paper.yaml").read_text())
    paths["net"].write_text((scenes / "networks" / "fead_i4.yaml").read_text())
    before = _digests(tmp_path)
    status, err = _sim([a.format(**paths) for a in argv] + ["--force"], capsys)
    assert status == 2 and len(err) == 1 and "would replace the scene file" in err[0], err
    assert _digests(tmp_path) == before
