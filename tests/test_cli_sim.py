"""``belt-drive sim``: files written, header, overwrite protection, one-line errors (no ROS needed)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from belt_drive_ros.cli import main
from belt_drive_ros.core.scene import Scene
from belt_drive_ros.io.scenes import load_scene, scene_yaml

HEADER = "time,phi_M,omega_M,phi_3,omega_3,drive_torque,load_torque,belt_torque,relative_deflection"
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _one_line_error(err: str) -> str:
    lines = [ln for ln in err.strip().splitlines() if ln.strip()]
    assert len(lines) == 1, err
    assert "Traceback" not in err
    assert lines[0].startswith("belt-drive: error:")
    return lines[0]


def test_sim_paper_writes_csv_and_png(tmp_path, capsys):
    csv, png = tmp_path / "run.csv", tmp_path / "run.png"
    code = main(["sim", "paper", "--duration", "0.5", "--out", str(csv), "--plot", str(png)])
    out = capsys.readouterr().out
    assert code == 0
    assert "paper" in out and f"wrote {csv}" in out and f"wrote {png}" in out
    lines = csv.read_text().splitlines()
    assert lines[0] == HEADER
    data = np.loadtxt(csv, delimiter=",", skiprows=1)
    scene = load_scene("paper")
    n = int(round(0.5 / scene.dt)) + 1
    assert data.shape == (n, 9)
    assert np.all(np.isfinite(data))
    np.testing.assert_allclose(data[:, 0], scene.dt * np.arange(n), rtol=1e-11, atol=1e-15)
    # Columns mean what the header says (12 significant digits in the file):
    i = scene.params.ratio
    phi_M, phi_3, defl = data[:, 1], data[:, 3], data[:, 8]
    np.testing.assert_allclose(defl, i * phi_M - phi_3, rtol=0, atol=1e-10 * max(1.0, np.max(np.abs(phi_M))))
    assert np.max(data[:, 2]) > 1.0  # the motor ran the drive up
    assert png.read_bytes()[:8] == PNG_MAGIC and png.stat().st_size > 10_000


def test_sim_refuses_to_overwrite_without_force(tmp_path, capsys):
    csv = tmp_path / "run.csv"
    csv.write_text("keep me\n")
    code = main(["sim", "paper", "--duration", "0.05", "--out", str(csv), "--quiet"])
    err = capsys.readouterr().err
    assert code == 2
    assert _one_line_error(err) == f"belt-drive: error: --out {csv} exists; pass --force to overwrite it"
    assert csv.read_text() == "keep me\n"
    code = main(["sim", "paper", "--duration", "0.05", "--out", str(csv), "--quiet", "--force"])
    assert code == 0
    assert csv.read_text().splitlines()[0] == HEADER


def test_unknown_scene_is_a_one_line_error(capsys):
    code = main(["sim", "no_such_scene", "--duration", "0.1"])
    err = capsys.readouterr().err
    assert code == 2
    line = _one_line_error(err)
    assert "no_such_scene" in line and "paper" in line


def test_bad_method_is_a_one_line_error(capsys):
    code = main(["sim", "paper", "--method", "rk5", "--duration", "0.1", "--quiet"])
    err = capsys.readouterr().err
    assert code == 2
    line = _one_line_error(err)
    assert "rk5" in line and "rk4" in line and "exact" in line


def test_unstable_step_is_a_one_line_error_naming_a_fix(capsys):
    code = main(["sim", "truck_compressor", "--model", "flexible", "--method", "rk4", "--dt", "0.01", "--duration", "0.1", "--quiet"])
    err = capsys.readouterr().err
    assert code == 2
    line = _one_line_error(err)
    assert "UNSTABLE" in line and "is stable and accurate" in line and "etd4 at dt" in line  # both guards accept it


def test_model_and_method_overrides(tmp_path, capsys):
    csv = tmp_path / "rigid.csv"
    code = main(["sim", "paper", "--model", "rigid", "--method", "rk4", "--dt", "0.002", "--duration", "0.1",
                 "--out", str(csv), "--quiet"])
    out = capsys.readouterr().out
    assert code == 0
    assert "rigid" in out and "rk4" in out
    data = np.loadtxt(csv, delimiter=",", skiprows=1)
    assert data.shape == (51, 9)
    # Rigid belt: wheel 3 follows i * phi_M exactly.
    np.testing.assert_allclose(data[:, 3], load_scene("paper").params.ratio * data[:, 1], rtol=1e-10, atol=1e-12)


def test_missing_scene_argument_is_usage_error(capsys):
    with pytest.raises(SystemExit) as info:
        main(["sim"])
    assert info.value.code == 2


def test_plot_overlay_does_not_fail_a_valid_run(tmp_path, capsys):
    """--model rigid --method rk4 --dt 0.05 is a stable, valid rigid run (no belt mode). The PNG
    overlays the flexible model too; that auxiliary run must not turn the requested one into
    an error (RK4 at h omega_n = 3.3 on the flexible belt diverges): fall back to a stable
    method or step for the overlay, or plot only the requested model, but write the PNG."""
    png = tmp_path / "rigid.png"
    code = main(["sim", "paper", "--model", "rigid", "--method", "rk4", "--dt", "0.05", "--duration", "1.0",
                 "--plot", str(png), "--quiet"])
    err = capsys.readouterr().err
    assert code == 0, err
    assert png.exists() and png.read_bytes()[:8] == PNG_MAGIC


@pytest.mark.parametrize("cut", ["60%", "last 30 bytes"])
def test_resimulating_a_cut_recording_is_a_one_line_error(tmp_path, capsys, cut):
    """``belt-drive sim REC.mcap`` on a recording cut off mid-write (a killed writer, a truncated copy): the mcap
    library's reader raised RecordLengthLimitExceeded through the command ('internal error', exit 1)."""
    rec = tmp_path / "rec.mcap"
    assert main(["sim", "paper", "--duration", "0.5", "--quiet", "--out", str(rec)]) == 0
    data = rec.read_bytes()
    cut_file = tmp_path / "cut.mcap"
    cut_file.write_bytes(data[: int(len(data) * 0.6)] if cut == "60%" else data[:-30])
    capsys.readouterr()
    assert main(["sim", str(cut_file), "--quiet", "--out", str(tmp_path / "re.mcap")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "cut.mcap" in err[0] and "internal error" not in err[0], err
    assert not (tmp_path / "re.mcap").exists()


def test_a_rigid_run_says_it_does_not_use_the_initial_deflection(tmp_path, capsys):
    """The rigid model has no belt deflection state: an initial relative deflection or speed in the scene is not
    used (wheel 3 starts at i phi_M). Not silently: sim warns, naming both values; without them, no warning."""
    scene = tmp_path / "s.yaml"
    scene.write_text("extends: paper\nduration: 0.05\ninitial_state: {relative_deflection: 0.01, relative_speed: 0.5}\n")
    assert main(["sim", str(scene), "--model", "rigid", "--method", "etd2", "--dt", "1e-3"]) == 0
    err = capsys.readouterr().err
    assert "warning: the rigid model has no belt deflection: initial_state.relative_deflection 0.01 rad and " \
           "relative_speed 0.5 rad/s are not used" in err
    assert main(["sim", str(scene), "--model", "flexible", "--method", "etd2", "--dt", "1e-3"]) == 0
    assert "no belt deflection" not in capsys.readouterr().err
    assert main(["sim", "paper", "--model", "rigid", "--method", "etd2", "--duration", "0.05"]) == 0
    assert "no belt deflection" not in capsys.readouterr().err


@pytest.mark.parametrize("argv, message", [
    (["--bag-folder"], "--bag-folder: writes --out as a rosbag2 bag folder; give --out NAME"),
    (["--plot-every", "5"], "--plot-every: thins what --plot draws; give --plot FILE.png"),
    (["--start-time", "0", "--out", "x.csv"], "--start-time: stamps the messages of an MCAP output; --out is x.csv, not one"),
    (["--start-time", "0"], "--start-time: stamps the messages of an MCAP output; --out is not given"),
    (["--method-option", "rtol=1e-6", "--method-option", "rtol=1e-9"], "--method-option rtol: given twice"),
])
def test_an_option_that_would_change_nothing_is_refused_not_ignored(argv, message, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["sim", "paper", "--duration", "0.01", *argv]) == 2
    assert capsys.readouterr().err.strip() == f"belt-drive: error: {message}"
    assert not (tmp_path / "x.csv").exists()


def test_scenes_of_an_unknown_name_lists_the_belt_networks_it_also_takes(capsys):
    assert main(["scenes", "nosuch"]) == 2
    err = capsys.readouterr().err
    assert "not a shipped scene (bsg_start, e_motor_start, paper, truck_compressor); nor a shipped belt network" in err
    assert "fead_i4" in err


def test_method_auto_that_meets_no_tolerance_warns(tmp_path, capsys):
    """``method: auto`` that finds no candidate within the tolerance says so on stderr, also where the run's own
    check then rates the chosen step accurate: a motor curve cut within 50 rad/s, tolerance 1e-6, chose etd4 at
    0.78 ms with 'estimated 4.3e-06' in its reason but printed no warning (the accuracy line said 9.7e-10;
    measured against DOP853 the run is 5.6e-6 off)."""
    paper = load_scene("paper").to_dict()
    scene = {**paper, "name": "motor_cut", "model": "flexible", "method": "auto", "dt": 0.05, "duration": 0.6,
             "tolerance": 1e-6, "params": {**paper["params"], "F_0": 4000.0},
             "drive": {"type": "motor", "curve": [[0.0, 30.0], [100.0, 30.0], [150.0, 0.0]], "soft_start_time": 0.05},
             "load": 2.0}
    path = tmp_path / "motor_cut.yaml"
    path.write_text(scene_yaml(Scene.from_mapping(scene)))
    assert main(["sim", str(path), "--quiet"]) == 0
    captured = capsys.readouterr()
    assert "no candidate" in captured.out  # (the method choice's own finding)
    assert "warning:" in captured.err and "1e-06" in captured.err


@pytest.mark.parametrize("method, options, rtol", [("BDF", [], "1e-06"), ("RK45", ["--method-option", "rtol=1e-9"], "1e-09")])
def test_an_adaptive_method_s_run_says_it_is_not_rated(capsys, method, options, rtol):
    """No guard rates an adaptive method against the tolerance (its rtol/atol bound each step's local error): the
    summary said nothing about accuracy at all (BDF at its default rtol on a belt with c = 0 was 7.4e-4 off against
    the tolerance 1e-4). It says the run is not rated, with the options in force."""
    assert main(["sim", "paper", "--method", method, "--duration", "0.2", *options]) == 0
    line = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("accuracy")]
    assert len(line) == 1 and "not rated" in line[0] and f"{method} is adaptive (rtol {rtol}" in line[0], line


def test_a_fixed_step_run_is_rated(capsys):
    """The counterpart: a fixed-step run's accuracy line is the guard's verdict, not the adaptive note."""
    assert main(["sim", "paper", "--duration", "0.2"]) == 0
    line = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("accuracy")]
    assert len(line) == 1 and "not rated" not in line[0] and "accurate" in line[0], line


@pytest.mark.parametrize("torque_bag", [False, True])
def test_an_offline_recording_resimulates_on_its_own_time_stamps(tmp_path, capsys, torque_bag):
    # re.mcap of an offline run was stamped at the wall time of the re-simulation, or at the first stamp of the
    # torque bag that drove it: a comparison on the common clock found no common time range
    from msg_tools import summary
    from msg_tools.cli import main as msg_tools

    from belt_drive_ros.io.bags import REFERENCE_BAGS

    rec, re_run = tmp_path / "rec.mcap", tmp_path / "re.mcap"
    args = ["sim", "paper", "--duration", "0.2", "--start-time", "1700000000", "--out", str(rec), "--quiet"]
    if torque_bag:
        bag = REFERENCE_BAGS["e_motor_start"].files(Path(__file__).resolve().parent.parent / "bags")["torque"]
        args = ["sim", "e_motor_start", "--torque-bag", str(bag), "--duration", "0.2", "--start-time", "1700000000",
                "--out", str(rec), "--quiet"]
        (tmp_path / bag.name).write_bytes(bag.read_bytes())
    assert main(args) == 0
    assert main(["sim", str(rec), "--out", str(re_run), "--quiet"]) == 0
    assert summary(re_run).start_ns == summary(rec).start_ns == 1_700_000_000_000_000_000
    capsys.readouterr()
    assert msg_tools(["compare", str(re_run), str(rec), "--time-base", "absolute", "--rtol", "0", "--atol", "0"]) == 0


@pytest.mark.parametrize("text, ns", [("1700000000.25", 1_700_000_000_250_000_000),
                                      ("1700000000.123456789", 1_700_000_000_123_456_789),
                                      ("2026-01-01T00:00:00.000001Z", 1_767_225_600_000_001_000)])
def test_a_start_time_is_taken_to_the_nanosecond(text, ns):
    # seconds times 1e9 in floats stamped 1700000000.25 as ...249999872 (the scene's time 0 128 ns early)
    from belt_drive_ros.io.recording import parse_start_time

    assert parse_start_time(text) == ns


def test_an_offline_recording_resimulates_at_the_rate_it_was_written(tmp_path, capsys):
    # write_result_mcap(output_rate=250) of a 1 kHz scene: the re-simulation wrote the scene's 1 kHz, and compare
    # interpolated the recording between its samples (23 of 45 signals failed)
    from msg_tools import summary
    from msg_tools.cli import main as msg_tools

    from belt_drive_ros.core.simulate import simulate
    from belt_drive_ros.io.recording import write_result_mcap

    rec, re_run = tmp_path / "rec.mcap", tmp_path / "re.mcap"
    run = simulate(load_scene("truck_compressor"), model="flexible", duration=0.1)
    write_result_mcap(run, rec, output_rate=250.0, start_time_ns=0)
    assert main(["sim", str(rec), "--out", str(re_run), "--quiet"]) == 0
    counts = [{t.topic: t.message_count for t in summary(f).topics} for f in (rec, re_run)]
    assert counts[0]["/shaft_speed"] == 26 and counts[1] == counts[0]
    capsys.readouterr()
    assert msg_tools(["compare", str(re_run), str(rec), "--rtol", "0", "--atol", "0"]) == 0


@pytest.mark.parametrize("options", [{"namespace": "/car1"}, {"topics": ["shaft_speed", "belt_torque"]}])
def test_an_offline_recording_resimulates_its_own_topics(tmp_path, capsys, options):
    # write_result_mcap(namespace="/car1"): the re-simulation wrote /shaft_speed ... and copied the recorded
    # /car1/shaft_speed ... into --out as they were (a compare of those passed whatever the run gave); topics=[...]:
    # it wrote every topic, and compare failed for those the recording has not
    from msg_tools import summary
    from msg_tools.cli import main as msg_tools

    from belt_drive_ros.core.simulate import simulate
    from belt_drive_ros.io.recording import write_result_mcap

    rec, re_run = tmp_path / "rec.mcap", tmp_path / "re.mcap"
    run = simulate(load_scene("truck_compressor"), model="flexible", duration=0.05)
    write_result_mcap(run, rec, start_time_ns=0, **options)
    assert main(["sim", str(rec), "--out", str(re_run), "--quiet"]) == 0
    assert "0 more recorded topic(s) copied" in capsys.readouterr().out
    topics = [{t.topic for t in summary(f).topics} for f in (rec, re_run)]
    assert topics[1] == topics[0]
    assert msg_tools(["compare", str(rec), str(re_run), "--rtol", "0", "--atol", "0"]) == 0


@pytest.mark.parametrize("model, topics", [("flexible", None), ("flexible", ["shaft_speed", "slip_speed"]),
                                           ("slipping", None)])
def test_a_recording_resimulates_on_another_model_with_that_models_topics(tmp_path, model, topics):
    # a slipping recording (its slip outputs among its topics) re-simulated --model flexible, and a flexible one
    # --model slipping: the run's model's topics, of those the recording has where it has a subset
    from msg_tools import summary

    from belt_drive_ros.core.simulate import simulate
    from belt_drive_ros.io.recording import write_result_mcap

    rec, re_run = tmp_path / "rec.mcap", tmp_path / "re.mcap"
    run = simulate(load_scene("truck_compressor"), model="slipping" if model == "flexible" else "flexible", duration=0.6)
    write_result_mcap(run, rec, start_time_ns=0, topics=topics)
    assert main(["sim", str(rec), "--model", model, "--out", str(re_run), "--quiet"]) == 0
    written = {t.topic for t in summary(re_run).topics}
    if topics:
        assert written == {"/shaft_speed"}
    else:
        assert ("/slip_speed" in written) == (model == "slipping") and "/shaft_speed" in written


def test_a_torque_bag_of_several_drives_is_read_on_the_topic_named(tmp_path, capsys):
    """A bag holding /a/drive_torque and /b/drive_torque could not drive a run: the refusal listed both with no way
    to pick one. --torque-topic names it; the run is driven by that topic's torque (5 N m on /a, 9 on /b)."""
    from mcap_ros2.writer import Writer

    bag = tmp_path / "two.mcap"
    with open(bag, "wb") as f:
        w = Writer(f)
        schema = w.register_msgdef("std_msgs/msg/Float64", "float64 data")
        for k in range(201):
            for topic, value in (("/a/drive_torque", 5.0), ("/b/drive_torque", 9.0)):
                w.write_message(topic, schema, {"data": value}, log_time=k * 10**6, publish_time=k * 10**6)
        w.finish()
    args = ["sim", "paper", "--torque-bag", str(bag), "--duration", "0.2", "--quiet"]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert "/a/drive_torque, /b/drive_torque" in err and "--torque-topic" in err and len(err.strip().splitlines()) == 1
    for topic, value in (("/a/drive_torque", 5.0), ("b/drive_torque", 9.0)):
        out = tmp_path / f"{value:g}.csv"
        assert main(args + ["--torque-topic", topic, "--out", str(out)]) == 0
        rows = np.loadtxt(out, delimiter=",", skiprows=1)
        header = out.read_text().splitlines()[0].split(",")
        assert np.all(rows[:, header.index("drive_torque")] == value)
    capsys.readouterr()
    assert main(["sim", "paper", "--torque-topic", "/a/drive_torque"]) == 2
    assert "--torque-topic" in capsys.readouterr().err


def test_method_auto_s_substeps_that_split_the_output_rate_are_said(tmp_path, capsys):
    """method auto at tolerance 1e-11 steps paper at 5 ms / 6: 1 kHz is then no whole number of steps and the file
    has a message at every step (1200 Hz), but the note that says so was decided before the choice (at 5 ms, where
    1 kHz is above the step rate) and was not printed."""
    from msg_tools import summary

    out = tmp_path / "x.mcap"
    assert main(["sim", "paper", "--method", "auto", "--tolerance", "1e-11", "--duration", "0.5", "--out", str(out),
                 "--quiet"]) == 0
    text = capsys.readouterr().out
    assert "6 substeps" in text
    assert "note: output_rate 1000 Hz is not the step rate 1200 Hz divided by a whole number" in text
    speed = [t for t in summary(out).topics if t.topic == "/shaft_speed"][0]
    assert speed.message_count == 601  # every step of 0.5 s at 1/1200 s, and t = 0
