"""msg_tools.compare and the msg-tools command line (no ROS needed)."""

import csv
import os
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from msg_tools import Ros2McapWriter, compare, read_topic
from msg_tools.cli import main

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
JOINTS = ["crank", "alternator", "wheel_3"]


def _run(path, *, k=1.0, n=400, dt_ns=1_000_000, t0_ns=10**9, velocity_scale=None, skip_topic=None,
         metadata=True, description=None):
    """A small 'simulation' bag: torque + joint states; k scales the dynamics; a text description first."""
    velocity_scale = velocity_scale or {}
    with Ros2McapWriter(path, force=True) as w:
        if metadata:
            w.add_metadata("units", {"/drive_torque": "N*m"})
        if description is not None:
            w.write("/robot_description", "std_msgs/msg/String", {"data": description}, t0_ns)
        for i in range(n):
            t = t0_ns + i * dt_ns
            s = (t - 10**9) * 1e-9
            if skip_topic != "/drive_torque":
                w.write("/drive_torque", "std_msgs/msg/Float64", {"data": 50.0 * np.sin(2 * np.pi * 3 * s)}, t)
            velocity = np.array([100.0 + 5 * np.sin(2 * np.pi * 3 * s), 250.0 + s, 60.0 * k])
            for j, joint in enumerate(JOINTS):
                velocity[j] *= velocity_scale.get(joint, 1.0)
            if skip_topic != "/joint_states":
                w.write("/joint_states", "sensor_msgs/msg/JointState", {
                    "header": {"stamp": {"sec": t // 10**9, "nanosec": t % 10**9}},
                    "name": JOINTS,
                    "position": velocity * s,
                    "velocity": velocity,
                    "effort": [12.0 * k, -3.0, 0.5],
                }, t)
    return path


@pytest.fixture
def golden(tmp_path):
    return _run(tmp_path / "golden.mcap")


# ------------------------------------------------------------------ compare
def test_identical_runs_pass(tmp_path, golden):
    fresh = _run(tmp_path / "fresh.mcap")
    report = compare(fresh, golden)
    assert report.passed
    assert len(report.signals) == 1 + 3 * len(JOINTS)
    assert all(s.time_base == "identical" and s.worst_abs_error == 0.0 for s in report.signals)
    assert {s.n_compared for s in report.signals} == {400}


def test_change_of_one_permille_fails_and_names_worst_signal(tmp_path, golden):
    changed = _run(tmp_path / "changed.mcap", velocity_scale={"wheel_3": 1.001})
    report = compare(changed, golden)
    assert not report.passed
    failed = {s.name for s in report.failures}
    assert failed == {"joint_states/velocity[wheel_3]", "joint_states/position[wheel_3]"}
    worst = {s.name: s for s in report.signals}["joint_states/velocity[wheel_3]"]
    assert worst.worst_abs_error == pytest.approx(0.06, rel=1e-9)
    assert worst.worst_rel_error == pytest.approx(1e-3, rel=1e-9)
    # worst = largest |a-b| / (atol + rtol|b|): ~1000 for both, atol tips velocity
    assert report.worst.name == "joint_states/velocity[wheel_3]"
    assert report.worst.tube_ratio == pytest.approx(1e3 / (1 + 1e-9 / (1e-6 * 60.0)), rel=1e-6)
    position = {s.name: s for s in report.signals}["joint_states/position[wheel_3]"]
    assert position.worst_abs_error == pytest.approx(0.06 * 0.399, rel=1e-9)
    assert compare(changed, golden, rtol=2e-3).passed


def test_tolerance_tube_edges(tmp_path, golden):
    rtol = 1e-6
    inside = _run(tmp_path / "in.mcap", velocity_scale={"crank": 1 + 0.5 * rtol})
    outside = _run(tmp_path / "out.mcap", velocity_scale={"crank": 1 + 3 * rtol})
    assert compare(inside, golden, topics=["/joint_states"], rtol=rtol, atol=0).passed
    assert not compare(outside, golden, topics=["/joint_states"], rtol=rtol, atol=0).passed
    # absolute tolerance alone: |a-b| up to 3e-6*105 ~ 3.2e-4 rad/s
    assert compare(outside, golden, topics=["joint_states"], rtol=0, atol=1e-3).passed


def test_different_sampling_is_interpolated(tmp_path, golden):
    # A sampled at 300 Hz on other instants than B (1 kHz): linear interpolation
    # of the 3 Hz torque sine has error <= (h^2/8) max|f''| = 50*(2*pi*3)^2*(1e-3)^2/8 ~ 2.2e-3
    a = _run(tmp_path / "a.mcap", n=120, dt_ns=3_333_333, t0_ns=10**9 + 500_000)
    report = compare(a, golden, topics=["/drive_torque"], rtol=0, atol=3e-3)
    (signal,) = report.signals
    assert signal.passed and signal.time_base == "absolute" and signal.n_compared == 120
    assert 1e-4 < signal.worst_abs_error < 2.3e-3
    assert not compare(a, golden, topics=["/drive_torque"], rtol=0, atol=1e-4).passed


def test_relative_time_base_for_runs_at_other_clock_times(tmp_path, golden):
    later = _run(tmp_path / "later.mcap", t0_ns=10**9)
    # same samples recorded 100 s later on the wall clock
    shifted = tmp_path / "shifted.mcap"
    data = read_topic(later, "/drive_torque")
    with Ros2McapWriter(shifted) as w:
        for t, v in zip(data.log_time_ns, data.data):
            w.write("/drive_torque", "std_msgs/msg/Float64", {"data": v}, int(t) + 100 * 10**9)
    report = compare(shifted, golden, topics=["/drive_torque"])
    assert report.passed and report.signals[0].time_base == "relative"
    assert not compare(shifted, golden, topics=["/drive_torque"], time_base="absolute").passed


def test_missing_topic_and_short_run_fail_with_reason(tmp_path, golden):
    no_torque = _run(tmp_path / "no_torque.mcap", skip_topic="/drive_torque")
    report = compare(no_torque, golden)
    bad = {s.name: s.reason for s in report.failures}
    assert bad == {"drive_torque": f"topic /drive_torque missing in A ({no_torque})"}
    short = _run(tmp_path / "short.mcap", n=200)
    report = compare(short, golden, topics=["/drive_torque"])
    assert not report.passed and "50.0% of B's samples" in report.signals[0].reason


def test_text_topic_in_one_file_only_is_skipped_not_failed(tmp_path, golden):
    """A topic without numeric signals (a URDF on /robot_description) that only the newer file has
    leaves nothing to compare: skipped with the reason; asked for by name it is missing (fails)."""
    described = _run(tmp_path / "described.mcap", description="<robot name='x'/>")
    report = compare(described, golden)
    assert report.passed and len(report.signals) == 1 + 3 * len(JOINTS)
    assert report.skipped == [("/robot_description", "std_msgs/msg/String has no numeric signals (only in A)")]
    named = compare(described, golden, topics=["/robot_description", "/drive_torque"])
    assert not named.passed and "missing in B" in named.failures[0].reason
    no_torque = _run(tmp_path / "no_torque.mcap", skip_topic="/drive_torque", description="<robot/>")
    assert not compare(no_torque, golden).passed  # a numeric topic missing still fails


def test_undecodable_topic_is_a_failure_not_a_crash(tmp_path, golden):
    bad = tmp_path / "bad.mcap"
    data = read_topic(golden, "/drive_torque")
    with Ros2McapWriter(bad) as w:
        for t in data.log_time_ns:  # parameter-list CDR (0x0003) is not supported
            w.write_raw("/drive_torque", "std_msgs/msg/Float64", b"\x00\x03\x00\x00" + bytes(8), int(t))
    report = compare(bad, golden, topics=["/drive_torque"])
    (signal,) = report.signals
    assert not signal.passed and signal.reason.startswith("cannot decode in A: /drive_torque")


# ---------------------------------------------------------------------- CLI
def _cli(capsys, *argv):
    status = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return status, out, err


def test_cli_compare_exit_codes_and_table(capsys, tmp_path, golden):
    same = _run(tmp_path / "same.mcap")
    status, out, err = _cli(capsys, "compare", same, golden)
    assert status == 0, err
    assert "PASS: 10 signals" in out and "joint_states/velocity[wheel_3]" in out
    changed = _run(tmp_path / "changed.mcap", k=1.001)  # the drive's k off by 0.1 %
    status, out, err = _cli(capsys, "compare", changed, golden, "--rtol", "1e-6")
    assert status == 1
    last = out.strip().splitlines()[-1]
    assert last.startswith("FAIL: 3 of 10 signals outside tolerance; worst: joint_states/")
    assert "FAIL" in [line.split()[-1] for line in out.splitlines() if line.startswith("joint_states/effort[crank]")][0]


def test_cli_info(capsys, golden):
    status, out, _ = _cli(capsys, "info", golden)
    assert status == 0
    # the fields `ros2 bag info` shows, then ours
    for field in ("Files:", "Bag size:", "Storage id:        mcap", "ROS Distro:        jazzy", "Duration:",
                  "Start:", "End:", "Messages:", "Profile:           ros2",
                  "Status:            complete (data checked against the summary section)"):
        assert field in out, field
    # the fast path reads the summary section alone and says that the data was not checked
    status, fast, _ = _cli(capsys, "info", golden, "--summary-only")
    assert status == 0
    assert "Status:            complete (summary section only; the data was not checked)" in fast
    assert [ln for ln in fast.splitlines() if "Count:" in ln] == [ln for ln in out.splitlines() if "Count:" in ln]
    row = [line for line in out.splitlines() if "Topic: /joint_states " in line][0]
    assert [c.strip() for c in row.split("|")[1:]] == [
        "Type: sensor_msgs/msg/JointState", "Count: 400", "Serialization Format: cdr", "Rate: 1000.0 Hz"]
    assert "units:" in out and "rosbag2:" in out


def test_cli_export_csv_with_units(capsys, tmp_path, golden):
    out_csv = tmp_path / "js.csv"
    status, _, err = _cli(capsys, "export", golden, "--topic", "/joint_states", "--out", out_csv)
    assert status == 0, err
    rows = list(csv.reader(out_csv.open()))
    assert rows[0][:3] == ["time [s]", "log_time [ns]", "stamp [s]"]
    assert "velocity[wheel_3] [rad/s]" in rows[0] and "effort[crank] [N*m]" in rows[0]
    assert len(rows) == 401
    col = rows[0].index("velocity[wheel_3] [rad/s]")
    assert float(rows[1][col]) == 60.0 and rows[2][0] == "0.001000000"
    status, out, _ = _cli(capsys, "export", golden, "--topic", "drive_torque")
    header = out.splitlines()[0].split(",")
    assert header == ["time [s]", "log_time [ns]", "drive_torque [N*m]"]


def test_cli_outputs_get_the_permissions_a_plain_write_gives(capsys, tmp_path, golden):
    """export/plot write through a temporary file; the result is 0o666 less the umask as open() makes it
    (not mkstemp's 0o600), and a file replaced with --force keeps its mode."""
    old = os.umask(0o022)
    try:
        for argv, path in ((("export", golden, "--topic", "/joint_states"), tmp_path / "js.csv"),
                           (("plot", golden), tmp_path / "run.png")):
            status, _, err = _cli(capsys, *argv, "--out", path)
            assert status == 0, err
            assert oct(path.stat().st_mode & 0o777) == oct(0o644)
        os.chmod(tmp_path / "js.csv", 0o640)
        status, _, err = _cli(capsys, "export", golden, "--topic", "/joint_states", "--out", tmp_path / "js.csv",
                              "--force")
        assert status == 0, err
        assert oct((tmp_path / "js.csv").stat().st_mode & 0o777) == oct(0o640)
    finally:
        os.umask(old)


def test_cli_plot_writes_png(capsys, tmp_path, golden):
    png = tmp_path / "run.png"
    status, _, err = _cli(capsys, "plot", golden, "--out", png)
    assert status == 0, err
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "4 panels" in err


@pytest.mark.parametrize(
    "argv, expected",
    [
        (["info", "{missing}"], "bag not found"),
        (["info", "{garbage}"], "not an MCAP file"),
        (["export", "{golden}", "--topic", "/nope"], "topic '/nope' not found"),
        (["compare", "{golden}"], "required: B"),
        (["frobnicate"], "invalid choice"),
        (["compare", "{golden}", "{golden}", "--rtol", "-1"], "tolerances must be >= 0"),
        (["plot", "{golden}", "--out", "{tmp}/no/dir/x.png"], "x.png"),
    ],
)
def test_cli_errors_are_one_line_exit_2(capsys, tmp_path, golden, argv, expected):
    garbage = tmp_path / "garbage.mcap"
    garbage.write_bytes(b"this is not an mcap file at all")
    names = {"missing": tmp_path / "missing.mcap", "garbage": garbage, "golden": golden, "tmp": tmp_path}
    status, out, err = _cli(capsys, *[a.format(**names) for a in argv])
    assert status == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("msg-tools: error: ") and expected in lines[0], err
    assert "Traceback" not in err


def test_cli_truncated_bag_warns_reads_and_exits_1(capsys, tmp_path, golden):
    raw = golden.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(raw[: len(raw) // 2])
    status, out, err = _cli(capsys, "info", cut)
    assert status == 1  # data lost (issue 24: exit 0 before)
    assert "Status:            INCOMPLETE" in out
    assert err.startswith("msg-tools: warning: ") and "recovered" in err


#: a recording of the node's six topics (make bags)
SHIPPED_GOLDEN = Path(__file__).resolve().parents[1] / "bags" / "engine_idle_golden.mcap"


def _cut_golden(tmp_path, golden, step=1000, lost_samples=True):
    """The golden file cut from its end back in ``step`` bytes until it reads incomplete and (with
    ``lost_samples``) lacks samples, as a recorder killed before it finished leaves it; the cut file
    and what it lacks per topic."""
    from msg_tools import read_bag

    raw = golden.read_bytes()
    whole = {t: len(d) for t, d in read_bag(golden).topics.items()}
    cut = tmp_path / "cut.mcap"
    for end in range(len(raw) - step, 0, -step):
        cut.write_bytes(raw[:end])
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            bag = read_bag(cut)
        if not bag.complete:
            lost = {t: n - len(bag.topics[t]) for t, n in whole.items() if n > len(bag.topics.get(t, ()))}
            if lost or not lost_samples:
                return cut, lost
    raise AssertionError("no cut lost samples")


@pytest.mark.parametrize("order", ["golden second", "golden first"])
def test_compare_fails_on_a_truncated_file_naming_what_it_lacks(capsys, tmp_path, order):
    """Issue 24: a golden file without its last samples passed (exit 0, a warning)."""
    golden = SHIPPED_GOLDEN
    cut, lost = _cut_golden(tmp_path, golden)
    assert len(lost) >= 5 and set(lost.values()) == {1}  # the last sample of most topics
    a, b = (golden, cut) if order == "golden second" else (cut, golden)
    status, out, err = _cli(capsys, "compare", a, b)
    assert status == 1, out
    verdict = out.splitlines()[-1]
    side = "B" if order == "golden second" else "A"
    assert verdict.startswith(f"FAIL: {side} ({cut}) is incomplete") and "--allow-incomplete" in verdict, verdict
    assert f"lacks the last samples of {len(lost)} topics" in verdict
    assert all(f"{topic} {n}" in verdict for topic, n in lost.items()), verdict
    status, out, err = _cli(capsys, "compare", a, b, "--allow-incomplete")
    assert status == 0 and out.splitlines()[-1].endswith("(of what was read: a file is incomplete)"), out
    assert "(note: " in out
    status, out, err = _cli(capsys, "compare", cut, cut)  # both cut: nothing to say what is lost
    assert status == 1 and "its last samples are missing" in out.splitlines()[-1]


def test_compare_folders_fail_a_row_with_a_truncated_file(capsys, tmp_path):
    golden = SHIPPED_GOLDEN
    cut, _ = _cut_golden(tmp_path, golden)
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    (tmp_path / "a" / "run.mcap").write_bytes(golden.read_bytes())
    (tmp_path / "b" / "run.mcap").write_bytes(cut.read_bytes())
    status, out, err = _cli(capsys, "compare", tmp_path / "a", tmp_path / "b")
    assert status == 1 and "B incomplete" in out and out.splitlines()[-1] == "FAIL: 1 of 1 recordings; first: run.mcap"
    assert _cli(capsys, "compare", tmp_path / "a", tmp_path / "b", "--allow-incomplete")[0] == 0


def test_module_entry_point_without_traceback(tmp_path):
    garbage = tmp_path / "garbage.mcap"
    garbage.write_bytes(b"\x00" * 64)
    proc = subprocess.run([sys.executable, "-m", "msg_tools.cli", "info", str(garbage)],
                          capture_output=True, text=True, cwd=REPO, timeout=60)
    assert proc.returncode == 2
    assert proc.stderr.startswith("msg-tools: error: ") and "Traceback" not in proc.stderr
    proc = subprocess.run([sys.executable, "-m", "msg_tools", "--help"],
                          capture_output=True, text=True, cwd=REPO, timeout=60)
    assert proc.returncode == 0 and "examples:" in proc.stdout and "compare" in proc.stdout


ROS_FREE = """
import sys
sys.modules["rclpy"] = None  # any 'import rclpy' now raises ImportError
import msg_tools, msg_tools.cli, msg_tools.compare
assert "matplotlib" not in sys.modules, "importing msg_tools must not import matplotlib"
sys.exit(msg_tools.cli.main(["compare", sys.argv[1], sys.argv[1]]))
"""


def test_works_with_rclpy_unimportable(golden):
    proc = subprocess.run([sys.executable, "-c", ROS_FREE, str(golden)],
                          capture_output=True, text=True, cwd=REPO, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert "PASS" in proc.stdout


def test_importing_msg_tools_does_not_import_rclpy():
    code = "import sys, msg_tools, msg_tools.cli, msg_tools.compare; print('rclpy' in sys.modules)"
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO, timeout=60)
    assert proc.stdout.strip() == "False", proc.stderr


def test_compare_fails_a_cut_file_that_holds_every_sample_unless_allowed(capsys, tmp_path):
    """Cut after its last data chunk (the summary lost): nothing the whole file has is missing, but the cut file
    was not finished and nothing in it says that what it holds is all it had: an incomplete file fails (issue:
    'compare fails when either file is incomplete, unless --allow-incomplete'); allowed, it passes."""
    cut, lost = _cut_golden(tmp_path, SHIPPED_GOLDEN, step=16, lost_samples=False)
    assert lost == {}
    status, out, err = _cli(capsys, "compare", SHIPPED_GOLDEN, cut)
    assert status == 1 and out.splitlines()[-1].startswith("FAIL") and "not finished" in out, out
    status, out, err = _cli(capsys, "compare", SHIPPED_GOLDEN, cut, "--allow-incomplete")
    assert status == 0 and out.splitlines()[-1].startswith("PASS"), out
    assert _cli(capsys, "info", cut)[0] == 1  # info cannot know what the lost end held: INCOMPLETE


def _floats(path, values, topic="/shaft_speed", t0_ns=10**9):
    with Ros2McapWriter(path, force=True) as w:
        for k, v in enumerate(values):
            w.write(topic, "std_msgs/msg/Float64", {"data": float(v)}, t0_ns + k * 1_000_000)
    return path


def test_edges_of_compare_export_and_plot_are_their_own_answers(tmp_path, capsys):
    """A joint_states channel without a message: compare says 'no samples in A' (exit 1), export 'has no messages to
    export', plot draws the rest (before: KeyError 'stamp_ns' / 'position'); --topics naming a topic in neither file is
    a failed signal, not KeyError '/nope'; equal infinities agree (inf - inf is NaN, which failed a file against
    itself); the verdict's time is said to be where the signal is farthest outside its tube."""
    empty = tmp_path / "empty_js.mcap"
    with Ros2McapWriter(empty, force=True) as w:
        w.add_topic("/joint_states", "sensor_msgs/msg/JointState")
        for k in range(50):
            w.write("/shaft_speed", "std_msgs/msg/Float64", {"data": float(k)}, 10**9 + k * 1_000_000)
    full = _run(tmp_path / "full.mcap", n=50)
    report = compare(empty, full, topics=["/joint_states"])
    assert not report.passed and [s.reason for s in report.signals] == ["no samples in A"]
    assert main(["export", str(empty), "-t", "/joint_states", "-o", str(tmp_path / "x.csv")]) == 2
    assert "topic /joint_states (sensor_msgs/msg/JointState) has no messages to export" in capsys.readouterr().err
    assert main(["plot", str(empty), "-o", str(tmp_path / "x.png")]) == 0
    report = compare(full, full, topics=["/nope"])
    assert [s.reason for s in report.signals] == ["topic /nope in neither file"]
    inf = _floats(tmp_path / "inf.mcap", [1.0, float("inf"), -float("inf"), 2.0] * 5)
    assert compare(inf, inf).passed
    finite = _floats(tmp_path / "finite.mcap", [1.0, 5.0, -float("inf"), 2.0] * 5)
    assert not compare(inf, finite).passed and compare(inf, finite).signals[0].worst_abs_error == float("inf")
    a = _floats(tmp_path / "a.mcap", [1.0] * 10 + [1.001] + [100.0] * 9)
    b = _floats(tmp_path / "b.mcap", [1.0] * 10 + [1.0] + [100.1] * 9)
    assert "abs err 1.000e-01; farthest outside its tube at t=" in compare(a, b).verdict()


@pytest.mark.parametrize("argv, message", [
    (["plot", "{bag}", "-o", "{tmp}/x.png", "--dpi", "100000"], "--dpi: 10 to 1000, got 100000"),
    (["export", "{bag}", "-t", "/shaft_speed", "-o", "/proc/x.csv"], "cannot write /proc/x.csv: cannot write into folder /proc"),
    (["plot", "{bag}", "-o", "/proc/x.png"], "cannot write /proc/x.png: cannot write into folder /proc"),
    (["export", "{bag}", "-t", "/shaft_speed", "-o", ""], "--out: an empty path; give a file name"),
])  # fmt: skip
def test_outputs_msg_tools_cannot_write_are_refused_in_one_line_before_reading(tmp_path, capsys, argv, message):
    """(before: bad_alloc as an internal error; '[Errno 2] ... /proc/.x.csv.u9xbn7ao.part', naming the hidden temporary
    file; an empty -o wrote to standard output with exit 0)"""
    bag = _floats(tmp_path / "b.mcap", [1.0, 2.0, 3.0])
    argv = [a.format(bag=bag, tmp=tmp_path) for a in argv]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0], err


def test_folder_compare_takes_upper_case_mcap_files_too(tmp_path):
    """fa/x.MCAP against fb/x.MCAP: compared as a recording (before: left out without a word)."""
    from msg_tools.compare import compare_folders, recordings_in

    for folder, last in (("fa", 3.0), ("fb", 4.0)):
        (tmp_path / folder).mkdir()
        _floats(tmp_path / folder / "x.MCAP", [1.0, 2.0, last])
    assert list(recordings_in(tmp_path / "fa")) == ["x.MCAP"]
    report = compare_folders(tmp_path / "fa", tmp_path / "fb")
    assert not report.passed


def test_auto_compares_runs_started_seconds_apart_from_their_starts(tmp_path, golden):
    """Two runs of the same scene stamped with the wall time a few seconds apart overlap partly: auto took that
    for a common clock and failed every signal ('common time range holds 78.3%'); it compares them from their starts
    now, as it did for runs that do not overlap at all."""
    later = _run(tmp_path / "later.mcap", t0_ns=10**9)
    data = read_topic(later, "/drive_torque")
    span = int(data.log_time_ns[-1] - data.log_time_ns[0])
    shifted = tmp_path / "shifted.mcap"
    with Ros2McapWriter(shifted) as w:
        for t, v in zip(data.log_time_ns, data.data):
            w.write("/drive_torque", "std_msgs/msg/Float64", {"data": v}, int(t) + span // 4)  # a quarter later
    report = compare(shifted, golden, topics=["/drive_torque"])
    assert report.passed and report.signals[0].time_base == "relative"
    assert not compare(shifted, golden, topics=["/drive_torque"], time_base="absolute").passed


def test_tf_transforms_are_compared_by_child_frame(tmp_path):
    """Every recording carries /tf; compare skipped it ('TFMessage has no numeric signals'), so a wrong wheel
    transform passed. Each transform's translation and rotation are signals now, named by its child frame."""
    def tf_bag(path, w_last):
        def message(w):
            return {"transforms": [
                {"header": {"stamp": {"sec": 1, "nanosec": 0}, "frame_id": "base_link"}, "child_frame_id": child,
                 "transform": {"translation": {"x": 0.1, "y": 0.0, "z": 0.0},
                               "rotation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": w if child == "wheel_3_link" else 1.0}}}
                for child in ("wheel_M_link", "wheel_3_link")]}
        with Ros2McapWriter(path) as writer:
            for i in range(20):
                writer.write("/tf", "tf2_msgs/msg/TFMessage", message(w_last if i == 19 else 1.0), 10**9 + i * 10**6)
        return path

    a, b = tf_bag(tmp_path / "a.mcap", 1.0), tf_bag(tmp_path / "b.mcap", 0.123)
    same = compare(a, tf_bag(tmp_path / "a2.mcap", 1.0))
    assert same.passed and "tf/transforms[wheel_3_link].transform.rotation.w" in [s.name for s in same.signals]
    report = compare(b, a)
    assert not report.passed and report.worst.name == "tf/transforms[wheel_3_link].transform.rotation.w"


def test_a_topic_logged_late_in_one_file_fails_whatever_its_lag(tmp_path):
    """The time base was chosen signal by signal: a /shaft_speed logged 5 ms late failed, 60 ms late passed (its own
    coverage fell under 99 %, so it alone was compared from its own start). One base for the file pair: both fail,
    and two runs started seconds apart still compare from their starts."""
    from belt_drive_ros.cli import main as belt_drive

    a = tmp_path / "a.mcap"
    assert belt_drive(["sim", "paper", "--start-time", "0", "--method", "etd4", "--out", str(a)]) == 0
    for lag in (5_000_000, 60_000_000):
        late = tmp_path / f"late{lag}.mcap"
        with Ros2McapWriter(late) as w:
            for topic in ("/shaft_speed", "/belt_torque"):
                data = read_topic(a, topic)
                shift = lag if topic == "/shaft_speed" else 0
                for t, v in zip(data.log_time_ns, data.data):
                    w.write(topic, "std_msgs/msg/Float64", {"data": float(v)}, int(t) + shift)
        report = compare(late, a, topics=["/shaft_speed", "/belt_torque"])
        result = {s.name: s.passed for s in report.signals}
        assert result == {"shaft_speed/data": False, "belt_torque/data": True}, (lag, report.table())
    # the whole file 100 s later: relative, passes (and says so)
    shifted = tmp_path / "shifted.mcap"
    with Ros2McapWriter(shifted) as w:
        for topic in ("/shaft_speed", "/belt_torque"):
            data = read_topic(a, topic)
            for t, v in zip(data.log_time_ns, data.data):
                w.write(topic, "std_msgs/msg/Float64", {"data": float(v)}, int(t) + 100 * 10**9)
    report = compare(shifted, a, topics=["/shaft_speed", "/belt_torque"])
    assert report.passed and report.time_base == "relative" and "time base: relative" in report.table()


def test_a_topic_without_messages_in_both_files_is_skipped_not_failed(tmp_path):
    """A channel declared and never written (a recorder's, a re-simulation's passthrough) in both of two identical
    files failed 'no samples in A'. Skipped, with the reason."""
    import struct

    from mcap.writer import Writer

    def write(path):
        with open(path, "wb") as f:
            w = Writer(f)
            w.start(profile="ros2", library="test")
            schema = w.register_schema("std_msgs/msg/Float64", "ros2msg", b"float64 data")
            x = w.register_channel("/x", "cdr", schema)
            w.register_channel("/empty", "cdr", schema)  # declared, never written
            for k in range(10):
                w.add_message(x, log_time=k * 10**6, publish_time=k * 10**6,
                              data=b"\x00\x01\x00\x00" + struct.pack("<d", float(k)))
            w.finish()
        return path

    report = compare(write(tmp_path / "a.mcap"), write(tmp_path / "b.mcap"))
    assert report.passed and ("/empty", "no messages in either file") in report.skipped
    assert [s.name for s in report.signals] == ["x/data"]


def test_a_tf_of_one_transform_per_message_and_a_varying_array_are_compared(tmp_path):
    """Only the leaves every message had were kept: a /tf whose messages carry one transform each, frames
    alternating (several broadcasters), had none and was skipped, its translations 1000x off passing; a
    Float64MultiArray whose length varies kept only layout.data_offset. Each leaf is now compared over the messages
    that have it."""
    from mcap_ros2.writer import Writer

    from msg_tools.schemas import schema_text

    tf_def = schema_text("tf2_msgs/msg/TFMessage")  # (with its dependencies, as a ros2msg schema holds them)
    sep = "\n" + "=" * 80 + "\n"
    array_def = ("std_msgs/MultiArrayLayout layout\nfloat64[] data" + sep + "MSG: std_msgs/MultiArrayLayout\n"
                 "MultiArrayDimension[] dim\nuint32 data_offset" + sep + "MSG: std_msgs/MultiArrayDimension\n"
                 "string label\nuint32 size\nuint32 stride\n")

    def write(path, scale, lengths):
        with open(path, "wb") as f:
            w = Writer(f)
            tf = w.register_msgdef("tf2_msgs/msg/TFMessage", tf_def)
            arr = w.register_msgdef("std_msgs/msg/Float64MultiArray", array_def)
            for k in range(40):
                t = k * 10_000_000
                frame = ("wheel_a", "wheel_b")[k % 2]
                msg = {"transforms": [{"header": {"stamp": {"sec": 0, "nanosec": t}, "frame_id": "base"},
                                       "child_frame_id": frame,
                                       "transform": {"translation": {"x": scale * k, "y": 0.0, "z": 0.0},
                                                     "rotation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}}}]}
                w.write_message("/tf", tf, msg, log_time=t, publish_time=t)
                n = lengths[k % len(lengths)]
                w.write_message("/arr", arr, {"layout": {"dim": [], "data_offset": 0},
                                              "data": [scale * (k + j) for j in range(n)]}, log_time=t, publish_time=t)
            w.finish()
        return path

    ok = write(tmp_path / "ok.mcap", 1.0, (2, 3))
    bad = write(tmp_path / "bad.mcap", 1000.0, (2, 3))
    same = compare(write(tmp_path / "same.mcap", 1.0, (2, 3)), ok)
    assert same.passed and {"tf/transforms[wheel_a].transform.translation.x",
                            "tf/transforms[wheel_b].transform.translation.x", "arr/data[2]"} <= {
        s.name for s in same.signals}
    report = compare(bad, ok)
    failed = {s.name for s in report.failures}
    assert "tf/transforms[wheel_a].transform.translation.x" in failed and "arr/data[2]" in failed
    assert not any(topic == "/tf" for topic, _ in report.skipped)


def test_a_gap_and_duplicates_both_files_share_are_no_holes_though_one_file_is_longer(tmp_path):
    """A gap or duplicate stamps both files have were excused only when the two time arrays were equal: with A one
    sample shorter, compare failed 'a gap ... in A' / '1 duplicate time stamps ... in A' for what B has too. And
    a duplicated stamp both files have now pairs each occurrence with the other's (interpolation took one of B's)."""
    def write(path, stamps, values):
        with Ros2McapWriter(path) as w:
            for t, v in zip(stamps, values):
                w.write("/x", "std_msgs/msg/Float64", {"data": float(v)}, int(t))
        return path

    stamps = [k * 1_000_000 for k in range(100)] + [k * 1_000_000 for k in range(300, 400)]  # a 0.2 s gap
    stamps = stamps[:150] + [stamps[150]] + stamps[150:]  # and one stamp twice
    values = [float(k) for k in range(len(stamps))]
    b = write(tmp_path / "b.mcap", stamps, values)
    a = write(tmp_path / "a.mcap", stamps[:-1], values[:-1])
    report = compare(a, b, max_gap_periods=5.0)
    assert report.passed, report.table()
    other = write(tmp_path / "other.mcap", stamps[:-1], values[:150] + [values[150] + 1.0] + values[151:-1])
    assert not compare(other, b).passed  # (the first occurrence differs: found)
    # duplicates and a gap only A has are holes (B sampled once at each ms throughout)
    assert "duplicate time stamps" in compare(
        a, write(tmp_path / "plain.mcap", range(0, 400_000_000, 1_000_000), range(400))).signals[0].reason
    gap_only = write(tmp_path / "gap_only.mcap", sorted(set(stamps)), range(len(set(stamps))))
    assert "a gap of" in compare(
        gap_only, write(tmp_path / "plain2.mcap", range(0, 400_000_000, 1_000_000), range(400))).signals[0].reason
