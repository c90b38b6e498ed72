"""Bad command-line input: one ``belt-drive: error:`` line naming what is wrong and exit 2, before anything runs."""

from __future__ import annotations

import os
import re

import pytest

from belt_drive_ros.cli import main


def _cases(tmp):
    a_file = tmp / "a_file.yaml"
    a_file.write_text("x: 1\n")
    return {
        "record --duration -1": (["record", "--out", str(tmp / "r.mcap"), "--duration", "-1"], "--duration: must be > 0 s"),
        "record --duration nan": (["record", "--out", str(tmp / "r.mcap"), "--duration", "nan"], "--duration: must be > 0 s"),
        "demo --duration -1": (["demo", "--duration", "-1", "--out-dir", str(tmp)], "--duration: must be finite and > 0 s"),
        "demo --duration inf": (["demo", "--duration", "inf", "--out-dir", str(tmp)], "--duration: must be finite and > 0 s"),
        "demo --out-dir a file": (["demo", "--no-live", "--out-dir", str(a_file)], "exists and is not a folder"),
        "make-bags --out a file": (["make-bags", "--out", str(a_file)], "exists and is not a folder"),
        "make-bags --out /dev/null": (["make-bags", "--out", "/dev/null"], "exists and is not a folder"),
        "modes --campbell x.txt": (["modes", "fead_i4", "--campbell", str(tmp / "x.txt")], "--campbell .*give a .png path"),
        "modes --runup x.csv": (["modes", "fead_i4", "--runup", str(tmp / "x.csv")], "--runup .*give a .png path"),
        "sim --bag-folder in a missing folder": (["sim", "paper", "--quiet", "--duration", "0.05", "--bag-folder", "--out",
                                                  str(tmp / "missing" / "bag")], "folder .*missing does not exist"),
        "bench --minutes -1": (["bench", "replay", "--quick", "--minutes", "-1", "--out", str(tmp)], "--minutes: must be > 0"),
        "bench --seconds nan": (["bench", "soak", "--quick", "--seconds", "nan", "--out", str(tmp)], "--seconds: must be > 0"),
        "bench --samples 0": (["bench", "campaign", "--quick", "--samples", "0", "--out", str(tmp)], "--samples: must be > 0"),
        "bench --out a file": (["bench", "kernel", "--quick", "--out", str(a_file)], "exists and is not a folder"),
        "urdf --out and --png the same": (["urdf", "fead_i4", "--out", str(tmp / "a.png"), "--png", str(tmp / "a.png")],
                                          "--out and --png name the same file"),
        "network sim --tolerance": (["sim", "fead_i4", "--tolerance", "nan", "--quiet", "--duration", "0.01"],
                                    "--tolerance: not available for a belt network scene"),
        "replay --rate 0": (["replay", str(a_file), "--rate", "0"], "--rate: must be 0.001 to 1000, got 0.0"),
        "replay --rate inf": (["replay", str(a_file), "--rate", "inf"], "--rate: must be 0.001 to 1000, got inf"),
        "replay --rate 1e-300": (["replay", str(a_file), "--rate", "1e-300"], "--rate: must be 0.001 to 1000, got 1e-300"),
        "replay --sync without --clock": (["replay", str(a_file), "--sync", "/joint_states"], "--sync: needs --clock"),
        "replay --start-offset nan": (["replay", str(a_file), "--start-offset", "nan"], "--start-offset: must be finite and >= 0 s"),
        "replay --wait-subscribers -1": (["replay", str(a_file), "--wait-subscribers", "-1"], "--wait-subscribers: must be >= 0"),
        "replay --delay -1": (["replay", str(a_file), "--delay", "-1"], "--delay: must be finite and >= 0 s"),
        "modes same PNG twice": (["modes", "fead_i4", "--campbell", str(tmp / "a.png"), "--runup", str(tmp / "a.png")],
                                 "--campbell and --runup name the same file"),
        # round 2
        "source --harmonics ,,,": (["source", "engine", "--harmonics", ",,,", "--print"],
                                   "source engine: argument --harmonics: expected comma-separated numbers"),
        "source --harmonics 40,,12": (["source", "engine", "--harmonics", "40,,12", "--print"], "--harmonics: expected"),
        "source --max-torque -5": (["source", "engine", "--max-torque", "-5", "--print"], "engine.max_torque: must be >= 0"),
        "source --initial-speed nan": (["source", "engine", "--initial-speed", "nan", "--print"],
                                       "--initial-speed: nan rad/s is outside"),
        "source --initial-speed 1e300": (["source", "motor", "--initial-speed", "1e300", "--print"], "--initial-speed: "),
        "network sim --method auto": (["sim", "fead_i4", "--method", "auto", "--quiet", "--duration", "0.01"],
                                      "--method auto: not available for a belt network scene .*name a method"),
        "network sim --method ''": (["sim", "fead_i4", "--method", "", "--quiet", "--duration", "0.01"],
                                    "--method: unknown integrator ''"),
        "record --out a folder": (["record", "--out", str(tmp), "--duration", "1"], "--out: .*a recording is an .mcap file"),
        "record --out x.txt": (["record", "--out", str(tmp / "x.txt"), "--duration", "1"], "a recording is an .mcap file"),
        "record --out in a missing folder": (["record", "--out", str(tmp / "missing" / "r.mcap"), "--duration", "1"],
                                             "--out .*: folder .*missing does not exist"),
        "record --out a folder named .mcap": (["record", "--out", str(tmp / "d.mcap"), "--duration", "1"],
                                              "--out .*d.mcap: a directory"),
        "argparse: sim --dt x": (["sim", "paper", "--dt", "x"], r"^belt-drive: error: sim: argument --dt: invalid float value: 'x'"),
        "argparse: source without a kind": (["source"], "source: the following arguments are required: KIND"),
        "argparse: unknown option": (["scenes", "--bogus"], "unrecognized arguments: --bogus"),
        "sim --out in a folder nothing can be written to": (["sim", "paper", "--quiet", "--duration", "0.01", "--out",
                                                             "/proc/x.csv"], "--out /proc/x.csv: cannot write into folder /proc"),
        "sim --bag-folder in a folder nothing can be written to": (["sim", "paper", "--quiet", "--duration", "0.01", "--out",
                                                                    "/proc/b", "--bag-folder"],
                                                                   "--out /proc/b: cannot write into folder /proc"),
        "sim --plot in a folder nothing can be written to": (["sim", "paper", "--quiet", "--duration", "0.01", "--plot",
                                                              "/proc/x.png"], "--plot /proc/x.png: cannot write into folder"),
        "sim --method-option =1": (["sim", "paper", "--quiet", "--duration", "0.01", "--method-option", "=1"],
                                   "--method-option expects KEY=VALUE, got '=1'"),
        "sim --method-option max_iter=2.5": (["sim", "paper", "--quiet", "--duration", "0.01", "--method", "trapezoidal",
                                              "--method-option", "max_iter=2.5"],
                                             "--method-option 'max_iter': not a whole number: '2.5'"),
        "sim ''": (["sim", "", "--quiet"], "unknown scene ''"),
        "sim nosuch": (["sim", "nosuch", "--quiet"], r"unknown scene 'nosuch': not a file and not a shipped scene "
                       r"\(bsg_start, e_motor_start, paper, truck_compressor\); nor a shipped belt network "
                       r"\(bsg_start_network, fead_i4, paper_network\)"),
        "scenes ''": (["scenes", ""], "unknown scene ''"),
        "modes ''": (["modes", ""], "unknown network scene ''"),
        "node --list-parameters ''": (["node", "--list-parameters", ""], "unknown scene ''"),
        "node --name 'a b'": (["node", "paper", "--name", "a b"], "node: argument --name: a ROS node name is letters"),
        "source --name ''": (["source", "engine", "--name", ""], "source engine: argument --name: a ROS node name"),
        "source --rate 0": (["source", "engine", "--rate", "0"], r"--rate: must be in \[0.1, 20000\] Hz, got 0.0"),
        "record --topics 'bad topic'": (["record", "--out", str(tmp / "x.mcap"), "--duration", "1", "--topics", "bad topic"],
                                        "--topics: 'bad topic' is not a topic name"),
        "demo --scene paper (a motor)": (["demo", "--scene", "paper", "--no-offline", "--no-network", "--out-dir", str(tmp)],
                                         "--scene paper: the live run drives the belt by the scene's engine; .* 'motor'"),
        "demo --scene paper with outputs": (["demo", "--scene", "paper", "--out-dir", str(tmp / "made_by_demo")],
                                            "--scene paper: the live run drives the belt by the scene's engine"),
        "demo --no-live --no-offline --no-network": (["demo", "--no-live", "--no-offline", "--no-network"],
                                                     "all three parts skipped: nothing to run"),
        "record --ros-args --bogus": (["record", "--out", str(tmp / "x.mcap"), "--duration", "1", "--ros-args", "--bogus"],
                                      r"--ros-args: unknown ROS arguments \['--bogus'\]"),
        "source --ros-args -p": (["source", "engine", "--ros-args", "-p"], "--ros-args: refused by rcl: .*-p"),
        "bench node --scene nonexistent": (["bench", "node", "--scene", "nonexistent", "--duration", "1"],
                                           "unknown scene 'nonexistent'"),
        "bench node -p garbage": (["bench", "node", "-p", "garbage", "--duration", "1"], "-p 'garbage': a node parameter is NAME:=VALUE"),
        "bench --out in /proc": (["bench", "stability", "--quick", "--out", "/proc/b"], "--out /proc/b: cannot make the folder"),
        "demo --out-dir in /proc": (["demo", "--out-dir", "/proc/d", "--duration", "1", "--scene", "truck_compressor"],
                                    "--out-dir /proc/d: cannot make the folder"),
        "bench hostile --only nonexistent": (["bench", "hostile", "--only", "nonexistent", "--out", str(tmp)],
                                             "--only: categories of 'bench hostile' .*got 'nonexistent'"),
        # a ROS stamp's seconds are int32: 2100 wrapped to sec = -192522496 (exit 0), fead_i4 an internal error
        "sim --start-time 2100": (["sim", "paper", "--start-time", "2100-01-01T00:00:00Z", "--out", str(tmp / "y.mcap")],
                                  "--start-time .*must be between 1970 and 2038-01-19T03:14:07Z"),
        "sim --start-time ending past 2038": (["sim", "paper", "--start-time", "2038-01-19T03:14:06Z", "--out",
                                               str(tmp / "y.mcap")], "--start-time: the run's last sample .*past 2038"),
        "network sim --start-time ending past 2038": (["sim", "fead_i4", "--start-time", "2038-01-19T03:14:07Z", "--out",
                                                       str(tmp / "f.mcap")], "--start-time: the run's last sample .*past 2038"),
    }


CASES = [
    "record --duration -1", "record --duration nan", "demo --duration -1", "demo --duration inf", "demo --out-dir a file",
    "make-bags --out a file", "make-bags --out /dev/null", "modes --campbell x.txt", "modes --runup x.csv", "modes same PNG twice",
    "sim --bag-folder in a missing folder", "bench --minutes -1", "bench --seconds nan", "bench --samples 0", "bench --out a file",
    "urdf --out and --png the same", "network sim --tolerance",
    "replay --rate 0", "replay --rate inf", "replay --rate 1e-300", "replay --sync without --clock", "replay --delay -1",
    "source --harmonics ,,,", "source --harmonics 40,,12", "source --max-torque -5", "source --initial-speed nan",
    "source --initial-speed 1e300", "network sim --method auto", "network sim --method ''", "record --out a folder",
    "record --out x.txt", "record --out in a missing folder", "record --out a folder named .mcap", "argparse: sim --dt x",
    "argparse: source without a kind", "argparse: unknown option", "sim --out in a folder nothing can be written to",
    "sim --plot in a folder nothing can be written to", "sim --method-option =1", "sim --method-option max_iter=2.5",
    "sim ''", "sim nosuch", "sim --bag-folder in a folder nothing can be written to", "scenes ''", "modes ''", "node --list-parameters ''",
    "node --name 'a b'", "source --name ''", "source --rate 0", "record --topics 'bad topic'", "demo --scene paper (a motor)", "demo --scene paper with outputs", "demo --no-live --no-offline --no-network",
    "record --ros-args --bogus", "source --ros-args -p", "bench node --scene nonexistent", "bench node -p garbage",
    "bench hostile --only nonexistent", "bench --out in /proc", "demo --out-dir in /proc", "replay --start-offset nan",
    "replay --wait-subscribers -1", "sim --start-time 2100", "sim --start-time ending past 2038",
    "network sim --start-time ending past 2038",
]


@pytest.mark.parametrize("case", CASES)
def test_bad_option_values_are_one_line_and_exit_2_before_anything_runs(case, tmp_path, capsys):
    """Before: record's --duration exited 1 (a SystemExit text), make-bags into a file exited 1 with
    '[Errno 17] File exists', demo started its ROS part with a negative --duration, modes wrote a PNG into
    x.txt (every other PNG option refuses that), sim --bag-folder made the missing parents of --out (a file
    --out says the folder does not exist), bench took a negative or nan --minutes/--seconds/--samples and an
    --out naming a file failed with exit 1 ('[Errno 17] File exists'), urdf wrote the URDF and then the PNG into
    one file, a network sim took any --tolerance (even nan) and ignored it, replay's --rate 0, --sync
    without --clock and a negative --delay exited 1 (a SystemExit text).
    Round 2, before: source took --harmonics ',,,' (no harmonics), a negative --max-torque (a constant -5 N m) and
    --initial-speed nan (it then published nothing); a network sim's --method auto said 'unknown integrator' and
    --method '' ran the scene's; record --out into a folder, a missing folder or x.txt exited 1 or wrote an MCAP
    named x.txt; argparse printed its usage block before its error line; an output in a folder nothing can be
    written to (/proc) ran first and then exited 1; --method-option =1 said 'lawson5: unknown option(s)' naming
    nothing; an empty scene name read the current folder ('scene file .: a directory') or listed every scene;
    node and source took any --name and source any --rate until rclpy refused them as an internal error (exit 1),
    and record a --topics name rcl refuses, leaving an empty recording behind; demo --scene paper (a motor) started
    its ROS nodes before it refused the scene; --ros-args that rclpy refuses were an internal error (exit 1), and
    record left an empty recording behind; bench node with an unknown scene or a -p without ':=' started its child and
    failed with an internal error; bench hostile --only of an unknown category printed a usage block; a bench --out or
    demo --out-dir that cannot be made said '[Errno 2] ...' naming no option (demo: after its 4 s live run); replay
    took --wait-subscribers -1 and checked --start-offset only after reading the whole bag."""
    (tmp_path / "d.mcap").mkdir()
    argv, message = _cases(tmp_path)[case]
    try:
        status = main(argv)
    except SystemExit as exc:  # (argparse's refusal, before: a usage block, then its error line)
        status = exc.code
    assert status == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("belt-drive: error: "), err
    assert re.search(message, err[0]), err
    assert not (tmp_path / "missing").exists() and not (tmp_path / "x.txt").exists() and not (tmp_path / "x.csv").exists() and not (tmp_path / "x.mcap").exists() and not (tmp_path / "a.png").exists()
    assert not (tmp_path / "made_by_demo").exists()  # (a refused demo made its --out-dir before: now nothing)


def test_campaign_from_python_takes_numpy_values_and_refuses_other_objects_naming_the_key():
    """Before: an np.float64 grid value or tolerance raised yaml's RepresenterError (the campaign's text is its
    YAML dump), an np.int64 grid value became the JSON text '20000' in the variant table, and a structure that
    holds itself recursed until RecursionError; an integer beyond 2^63 in a grid or as the seed raised
    OverflowError, 1e300 samples numpy's ValueError, and a profile given as a number (a constant, as a scene takes
    it) a TypeError in scene_of."""
    import numpy as np

    from belt_drive_ros.campaign.spec import Campaign, CampaignError

    plain = {"scene": "paper", "grid": {"params.k": [2.0e4, 1.5e4], "params.F_0": [400, 420]},
             "monte_carlo": {"samples": 3, "seed": 7, "vary": {"c": {"normal": 0.05, "absolute": False}}}}
    numpy = {"scene": "paper", "grid": {"params.k": np.array([2.0e4, 1.5e4]), "params.F_0": [np.int64(400), np.int64(420)]},
             "monte_carlo": {"samples": np.int64(3), "seed": np.uint8(7),
                             "vary": {"c": {"normal": np.float64(0.05), "absolute": np.bool_(False)}}}}
    a, b = Campaign.from_mapping(plain), Campaign.from_mapping(numpy)
    assert a.text == b.text and a.digest() == b.digest()
    assert a.variants().equals(b.variants()) and str(b.variants()["params.F_0"].dtype) == "int64"
    loop: dict = {}
    loop["set"] = loop
    for data, message in (({"scene": "paper", "set": {"dt": object()}}, "set.dt: object .* is not a campaign value"),
                          ({"scene": "paper", "grid": {"params.k": [1j]}}, r"grid.params.k\[0\]: complex"),
                          ({"scene": "paper", "set": loop}, "nested deeper than 32 levels"),
                          ({"scene": "paper", "grid": {"params.k": [10**400]}}, r"grid.params.k\[0\]: an integer beyond 2\^63"),
                          ({"scene": "paper", "monte_carlo": {"samples": 2, "seed": 10**400, "vary": {"c": {"normal": 0.1}}}},
                           "monte_carlo.seed: an integer beyond 2\\^63")):
        with pytest.raises(CampaignError, match=message):
            Campaign.from_mapping(data)
    with pytest.raises(CampaignError, match="monte_carlo.samples: 1e.300 is outside"):
        Campaign.from_mapping({"scene": "paper", "monte_carlo": {"samples": 1e300, "vary": {"c": {"normal": 0.1}}}})
    huge = Campaign.from_mapping({"scene": "paper", "monte_carlo": {"samples": 10**12, "vary": {"c": {"normal": 0.1}}}})
    with pytest.raises(CampaignError, match="1e.12 variants, more than the 1,000,000 variants one campaign may hold"):
        huge.variants()  # (numpy's 'Maximum allowed size exceeded', or all memory)
    constant = Campaign.from_mapping({"scene": "paper", "profiles": [{"load": 3.0}, {"load": np.float32(4.0)}]})
    assert [constant.scene_of(row).load.value for row in constant.variants().to_dict("records")] == [3.0, 4.0]


@pytest.mark.parametrize("text", ["{type: engine, speed_setpoint: 80, max_torque: -5}", "{type: engine, governor_gain: -1}"])
def test_engine_torque_limit_and_gain_are_not_negative(text):
    """Before: max_torque -5 was taken (the governor's clip(., 0, -5) is -5 N m whatever the speed)."""
    import yaml

    from belt_drive_ros.core.errors import SceneError
    from belt_drive_ros.core.sources import make_profile

    with pytest.raises(SceneError, match=r"drive: engine\.(max_torque|governor_gain): must be >= 0, got -"):
        make_profile(yaml.safe_load(text), "drive")


def test_bench_node_writes_nothing_into_the_current_folder_without_out(tmp_path, monkeypatch, capsys):
    """Before: 'belt-drive bench node' (and node-tick, replay) made docs/bench in the current folder and wrote
    node.csv and node.md there. Now the figures are printed and tables written only into an --out asked for."""
    import sys
    import types

    from belt_drive_ros.commands import bench

    seen = []
    monkeypatch.setitem(sys.modules, "belt_drive_ros.benchmarks.node", types.SimpleNamespace(main=lambda argv: seen.append(argv) or 0))
    monkeypatch.setitem(sys.modules, "belt_drive_ros.benchmarks.node_tick", types.SimpleNamespace(main=lambda quick, baseline=None: 0))
    monkeypatch.setattr(bench, "_single_threaded_blas", lambda: "BLAS as configured (test)")
    monkeypatch.chdir(tmp_path)
    assert main(["bench", "node", "--duration", "5"]) == 0 and main(["bench", "node-tick", "--quick"]) == 0
    assert seen == [["--duration", "5.0"]] and list(tmp_path.iterdir()) == []


def _torque_bag(path, samples, scene_yaml=None):
    """An MCAP of std_msgs/msg/Float64 on /drive_torque: ``samples`` is [(log time [ns], torque [N m])]; with
    ``scene_yaml``, a ``scene`` metadata record as belt_drive_ros writes one."""
    import struct

    from mcap.writer import Writer

    with open(path, "wb") as f:
        writer = Writer(f)
        writer.start(profile="ros2", library="test")
        schema = writer.register_schema(name="std_msgs/msg/Float64", encoding="ros2msg", data=b"float64 data\n")
        channel = writer.register_channel(topic="/drive_torque", message_encoding="cdr", schema_id=schema)
        for seq, (t, v) in enumerate(samples):
            writer.add_message(channel_id=channel, log_time=t, publish_time=t, data=b"\0\1\0\0" + struct.pack("<d", v),
                               sequence=seq)
        if scene_yaml is not None:
            writer.add_metadata("scene", {"yaml": scene_yaml})
        writer.finish()
    return path


@pytest.mark.parametrize("case", ["torque 1e300", "stamped past 2^63 ns"])
def test_torque_bag_with_absurd_torques_or_times_is_one_line_and_exit_2(case, tmp_path, capsys):
    """Before: a recorded torque of 1e300 N m ran and exited 1 ('simulation diverged ... reduce dt'); a message
    stamped at or past 2^63 ns exited 1 with 'internal error: OverflowError' (msg-tools export too)."""
    from msg_tools.cli import main as msg_tools

    start = 2**63 if case.startswith("stamped") else 10**9
    samples = [(start + k * 10**6, 1e300 if case == "torque 1e300" and k == 5 else 5.0) for k in range(50)]
    bag = _torque_bag(tmp_path / "bag.mcap", samples)
    out = tmp_path / "run.csv"
    assert main(["sim", "paper", "--torque-bag", str(bag), "--quiet", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and re.search("beyond (the plausible .-1e.06 N m|2.63 ns)", err[0]), err
    assert not out.exists() and list(tmp_path.iterdir()) == [bag]
    if case.startswith("stamped"):
        assert msg_tools(["export", str(bag), "--topic", "/drive_torque", "--out", str(out)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "beyond 2^63 ns" in err[0] and not out.exists(), err


def test_harness_parameters_numpy_unknown_huge_and_advance_bounds():
    """Before: BeltDriveHarness(bogus_param=1) ran, the parameter silently dropped by rclpy; k=10**400 raised
    SystemError from rclpy's conversion; numpy scalars (np.float32, np.int64) raised TypeError in the constructor
    and set_parameters; set_parameters(bogus=1) raised ParameterNotDeclaredException ('[]'); advance(nan) said
    'cannot convert float NaN to integer' and advance(1e9) ran for days."""
    import numpy as np

    from belt_drive_ros.ros.parameter_schema import NodeConfigError
    from belt_drive_ros.testing import BeltDriveHarness

    for params, message in (({"bogus_param": 1}, "bogus_param: not a parameter of the node"),
                            ({"k": 10**400}, "k: an integer beyond 2.63")):
        with pytest.raises(NodeConfigError, match=message):
            BeltDriveHarness(scene="paper", **params).start()
    with pytest.raises(NodeConfigError, match="^iput_timeout: not a parameter of the node"):  # ros_args too
        BeltDriveHarness(scene="paper", ros_args=["--ros-args", "-p", "c:=3", "-p", "iput_timeout:=0.5"]).start()
    with BeltDriveHarness(scene="paper", model="flexible", method="exact", substeps=np.int64(1), k=np.float32(2.0e4)) as h:
        assert h.node.get_parameter("k").value == 2.0e4
        result = h.set_parameters(bogus=1)
        assert not result.successful and result.reason == "bogus: not a parameter of the node"
        assert h.set_parameters(k=np.float64(2.1e4), step_rate_hz=np.int64(1000)).successful
        for seconds in (float("nan"), 1e9, -1.0):
            with pytest.raises(ValueError, match="advance: seconds must be >= 0 and at most 1e7"):
                h.advance(seconds)
        h.advance(np.float64(0.005))
        assert len(h.outputs()["shaft_speed"]) >= 5


@pytest.mark.parametrize("target", ["/dev/zero", "a FIFO"])
def test_recording_whose_scene_names_a_device_or_fifo_as_its_torque_bag_is_refused_not_hashed_forever(target, tmp_path, capsys):
    """Before: 'belt-drive sim REC.mcap' of a recording whose scene record names /dev/zero (or a FIFO) as the bag
    its torque was recorded in hashed it to check its sha256: it never ended (a FIFO: blocked in open)."""
    import os

    import yaml

    from belt_drive_ros.io.scenes import load_scene

    if target == "a FIFO":
        os.mkfifo(tmp_path / "fifo.mcap")
        target = "fifo.mcap"
    scene = dict(load_scene("paper").to_dict(), drive={"type": "recorded", "bag": target, "sha256": "0" * 64})
    rec = _torque_bag(tmp_path / "rec.mcap", [(10**9 + k * 10**6, 5.0) for k in range(20)], yaml.safe_dump(scene))
    assert main(["sim", str(rec), "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and re.search("the recorded torque bag .*(a character device|a FIFO)", err[0]), err


@pytest.mark.parametrize("text, message", [("0,1e300\n1,2\n", r"table.values: 1e\+300 N m is outside the plausible range"),
                                           ("1e300,1\n2e300,2\n", r"table.times: 2e\+300 s is outside the plausible range"),
                                           ("0,1\n0,2\n", "table.times: must be strictly increasing")])
def test_source_csv_profile_is_checked_as_a_scene_table_naming_the_file(text, message, tmp_path, capsys):
    """Before: a CSV torque of 1e300 N m (or times of 1e300 s) was taken and published; other refusals did not
    name the file."""
    csv = tmp_path / "torque.csv"
    csv.write_text(text)
    assert main(["source", "profile", "--csv", str(csv), "--print"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"belt-drive: error: {csv}: ") and re.search(message, err[0]), err


@pytest.mark.parametrize("text, column, values", [
    ("torque,time\n5,0\n7,1\n", None, [5.0, 7.0]),  # the torque: not the time column again
    ("time,drive_torque,load_torque\n0,5,1\n1,7,2\n", None, [5.0, 7.0]),
    ("time,a,b\n0,5,1\n1,7,2\n", "b", [1.0, 2.0]),
])
def test_source_csv_profile_takes_the_torque_column_beside_the_time(text, column, values, tmp_path):
    """A header 'torque,time': the time column was found by name, the torque defaulted to column 2, the time again,
    so the published torque was the time."""
    from belt_drive_ros.commands.source import read_csv_profile

    csv = tmp_path / "torque.csv"
    csv.write_text(text)
    table = read_csv_profile(csv, column)
    assert list(table.times) == [0.0, 1.0] and list(table.values) == values


@pytest.mark.parametrize("text, message", [("0,1.0.0\n1,2\n", "not a numeric CSV"),
                                           ("0x10,1\n1,2\n", "not a numeric CSV"),
                                           ("time,torque\n0,1\n", None)])
def test_source_csv_a_first_row_with_a_typo_is_an_error_not_a_header(text, message, tmp_path, capsys):
    """A first data row that failed to parse ('0,1.0.0') was taken as a header and dropped without a word (exit 0);
    --column naming the time column is refused."""
    csv = tmp_path / "torque.csv"
    csv.write_text(text)
    code = main(["source", "profile", "--csv", str(csv), "--print"])
    err = capsys.readouterr().err
    if message is None:
        assert code == 0 and main(["source", "profile", "--csv", str(csv), "--column", "time", "--print"]) == 2
        assert "--column 'time' is the time column" in capsys.readouterr().err
    else:
        assert code == 2 and message in err


def test_a_reader_that_leaves_before_the_summary_ends_the_run_quietly():
    """`belt-drive sim paper | head -1`: the reader has gone when the summary is printed. Like any filter the run
    ends with the status a shell gives a process ended by SIGPIPE (141) and prints nothing about it (before: exit 1,
    'belt-drive: error: [Errno 32] Broken pipe')."""
    import subprocess
    import sys

    env = {**os.environ, "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}
    proc = subprocess.Popen([sys.executable, "-m", "belt_drive_ros.cli", "sim", "paper", "--quiet", "--duration", "0.5"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env)  # fmt: skip
    proc.stdout.close()  # before the run writes a line
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=120) == 141 and err == "", err


def test_urdf_refuses_an_empty_out_and_lists_the_belt_networks_for_an_unknown_name(capsys):
    """(before: `urdf --out ''` wrote the URDF to standard output with exit 0; an unknown name listed the drive scenes
    only, though urdf takes the belt networks too)"""
    assert main(["urdf", "paper", "--out", ""]) == 2
    assert "--out: an empty path; give a file name" in capsys.readouterr().err
    assert main(["urdf", "nosuch"]) == 2
    assert "nor a shipped belt network (bsg_start_network, fead_i4, paper_network)" in capsys.readouterr().err
