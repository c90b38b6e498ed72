"""The reference bags in bags/: present, small, self-describing, and reproduced by fresh offline runs."""

import os
from pathlib import Path

import pytest
import yaml

from belt_drive_ros.io.bags import REFERENCE_BAGS, make_bags
from belt_drive_ros.cli import main as belt_drive
from belt_drive_ros.io.torque_bag import scene_from_bag
from belt_drive_ros.io.scenes import load_scene
from msg_tools import summary
from msg_tools.cli import main as msg_tools

BAGS = Path(__file__).resolve().parent.parent / "bags"
NAMES = list(REFERENCE_BAGS)
OUTPUTS = {"/drive_torque", "/joint_states", "/shaft_speed", "/load_torque", "/belt_torque", "/relative_deflection"}


def test_the_four_reference_cases():
    assert NAMES == ["engine_idle", "engine_runup", "e_motor_start", "compressor_cycling"]


@pytest.mark.parametrize("name", NAMES)
def test_reference_files_are_small_complete_and_self_describing(name):
    files = REFERENCE_BAGS[name].files(BAGS)
    for path in files.values():
        assert path.is_file(), f"{path} missing: run 'make bags'"
        assert path.stat().st_size < 2 * 1024 * 1024
    torque, golden = summary(files["torque"]), summary(files["golden"])
    for info in (torque, golden):
        assert info.complete and info.profile == "ros2" and info.compression == ["zstd"]
    assert [t.topic for t in torque.topics] == ["/drive_torque"]
    assert torque.topics[0].frequency_hz == pytest.approx(1000.0)
    assert {t.topic for t in golden.topics} == OUTPUTS
    ref = yaml.safe_load(golden.metadata_dict("scene")["yaml"])["drive"]
    assert ref["type"] == "recorded" and ref["bag"] == files["torque"].name
    # the scene file, the golden's metadata and the torque bag describe the same run
    scene = scene_from_bag(files["golden"])
    assert scene.params == load_scene(files["scene"]).params
    assert scene.model == load_scene(files["scene"]).model != "auto"


@pytest.mark.parametrize("name", NAMES)
def test_fresh_offline_run_matches_golden(name, tmp_path, capsys):
    files = REFERENCE_BAGS[name].files(BAGS)
    fresh = tmp_path / "fresh.mcap"
    assert belt_drive(["sim", str(files["scene"]), "--torque-bag", str(files["torque"]), "--out", str(fresh),
                       "--quiet"]) == 0
    capsys.readouterr()
    assert msg_tools(["compare", str(fresh), str(files["golden"])]) == 0
    out = capsys.readouterr().out
    assert out.strip().splitlines()[-1].startswith("PASS: 17 signals")


def test_compare_detects_a_permille_change_of_k(tmp_path, capsys):
    files = REFERENCE_BAGS["engine_idle"].files(BAGS)
    data = yaml.safe_load(files["scene"].read_text())
    data["params"]["k"] *= 1.001
    changed = tmp_path / "stiffer.yaml"
    changed.write_text(yaml.safe_dump(data, sort_keys=False))
    fresh = tmp_path / "fresh.mcap"
    assert belt_drive(["sim", str(changed), "--torque-bag", str(files["torque"]), "--out", str(fresh),
                       "--quiet"]) == 0
    capsys.readouterr()
    assert msg_tools(["compare", str(fresh), str(files["golden"])]) == 1
    verdict = capsys.readouterr().out.strip().splitlines()[-1]
    assert verdict.startswith("FAIL:") and "outside tolerance" in verdict


def test_regeneration_reproduces_the_committed_bags(tmp_path, capsys):
    written = make_bags(tmp_path, only=["engine_idle"], log=lambda line: None)
    assert [p.name for p in written] == ["engine_idle.yaml", "engine_idle_torque.mcap", "engine_idle_golden.mcap"]
    assert (tmp_path / "engine_idle.yaml").read_text() == (BAGS / "engine_idle.yaml").read_text()
    for kind in ("torque", "golden"):
        assert msg_tools(["compare", str(tmp_path / f"engine_idle_{kind}.mcap"),
                          str(BAGS / f"engine_idle_{kind}.mcap")]) == 0
    capsys.readouterr()
    # never overwrites without force, and says so in one line
    assert belt_drive(["make-bags", "--out", str(tmp_path), "--only", "engine_idle"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    # (the one sentence of every overwrite refusal, as the record and sim commands and msg-tools word it)
    assert err == [f"belt-drive: error: {tmp_path / 'engine_idle.yaml'} exists (and 2 more file(s) it would write); "
                   "pass --force to overwrite it"], err
    assert os.path.getsize(tmp_path / "engine_idle_golden.mcap") > 0


def test_regeneration_is_byte_identical_run_after_run(tmp_path):
    """What bags/README.md promises: the same code gives the same bytes (no wall-clock time, no randomness)."""
    first = make_bags(tmp_path / "a", only=["engine_idle"], log=lambda line: None)
    second = make_bags(tmp_path / "b", only=["engine_idle"], log=lambda line: None)
    for a, b in zip(first, second):
        assert a.read_bytes() == b.read_bytes(), a.name


@pytest.mark.parametrize("name", NAMES)
def test_bags_start_where_their_readme_says(name):
    """Scene time t is stamped 2026-01-01T00:00:00Z + t (BAGS_START_NS), as bags/README.md says."""
    from mcap.reader import make_reader

    from belt_drive_ros.io.bags import BAGS_START_NS

    assert BAGS_START_NS == 1_767_225_600 * 10**9  # 2026-01-01T00:00:00Z
    assert "2026-01-01T00:00:00Z" in (BAGS / "README.md").read_text(encoding="utf-8")
    for kind in ("torque", "golden"):
        with open(REFERENCE_BAGS[name].files(BAGS)[kind], "rb") as f:
            stats = make_reader(f).get_summary().statistics
        assert stats.message_start_time == BAGS_START_NS, kind


def test_a_scene_record_of_another_format_is_refused_not_read(tmp_path, capsys, monkeypatch):
    """A recording whose scene record says 'belt_drive_ros scene 99' (a later version's) was read as this one's."""
    from belt_drive_ros.cli import main
    from belt_drive_ros.io import bag_layout

    rec = tmp_path / "run.mcap"
    monkeypatch.setattr(bag_layout, "SCENE_FORMAT", "belt_drive_ros scene 99")
    assert main(["sim", "paper", "--duration", "0.02", "--method", "etd4", "--out", str(rec)]) == 0
    monkeypatch.undo()
    capsys.readouterr()
    assert main(["sim", str(rec), "--out", str(tmp_path / "re.mcap")]) == 2
    assert "its 'scene' record is format 'belt_drive_ros scene 99'; this version reads 'belt_drive_ros scene 1'" \
        in capsys.readouterr().err


def test_a_resimulated_scene_names_its_torque_bag_once(tmp_path):
    # the golden's scene record already says where its torque was recorded: re-reading it said so once more, and
    # each re-simulation of a re-simulation once again
    files = REFERENCE_BAGS["engine_idle"].files(BAGS)
    note = f"Drive torque recorded in {files['torque'].name}."
    scene = scene_from_bag(files["golden"])
    assert scene.description.count(note) == 1 and scene.description.endswith(note)
    again = tmp_path / "again.mcap"
    (tmp_path / files["torque"].name).write_bytes(files["torque"].read_bytes())
    assert belt_drive(["sim", str(files["golden"]), "--out", str(again), "--quiet"]) == 0
    assert scene_from_bag(again).description == scene.description
