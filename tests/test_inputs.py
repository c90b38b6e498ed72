"""Bounded inputs (issue 13): scene and profile files from outside never crash, hang or mislead.

Each case goes through the real loader (:func:`load_scene`) and, where it is
a CLI promise, through ``belt_drive_ros.cli.main`` (exit 2, one line).
"""

from __future__ import annotations

import math
import os
import subprocess
import sys

import pytest
import yaml

from belt_drive_ros.cli import main
from belt_drive_ros.core.errors import InputError, ParameterError, SceneError, short
from belt_drive_ros.io.inputs import MAX_DEPTH, SCENE_LIMIT, parse_yaml, read_text
from belt_drive_ros.core.scene import RANGES, Scene
from belt_drive_ros.io.scenes import load_scene
from belt_drive_ros.core.simulate import simulate


def _paper_dict() -> dict:
    return load_scene("paper").to_dict()


def _write(tmp_path, data, name="s.yaml") -> str:
    path = tmp_path / name
    if isinstance(data, (bytes, bytearray)):
        path.write_bytes(data)
    else:
        path.write_text(data if isinstance(data, str) else yaml.safe_dump(data, sort_keys=False))
    return str(path)


def _cli_error(capsys, argv) -> str:
    code = main(argv)
    err = capsys.readouterr().err
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("belt-drive: error: "), err
    assert "Traceback" not in err
    return lines[0]


# ------------------------------------------------------------------ what a file is
def test_device_is_refused_without_reading_it(capsys):
    with pytest.raises(InputError, match="character device"):
        load_scene("/dev/zero")
    line = _cli_error(capsys, ["sim", "/dev/zero", "--quiet"])
    assert "/dev/zero" in line and "regular file" in line


def test_directory_is_refused(tmp_path, capsys):
    line = _cli_error(capsys, ["sim", str(tmp_path), "--quiet"])
    assert "directory" in line


def test_fifo_does_not_block(tmp_path):
    """A FIFO nobody writes to: ``open`` would block for ever; the loader refuses it from stat (subprocess: a hang fails)."""
    fifo = tmp_path / "scene.yaml"
    os.mkfifo(fifo)
    proc = subprocess.run(
        [sys.executable, "-m", "belt_drive_ros.cli", "sim", str(fifo), "--quiet"],
        capture_output=True, text=True, timeout=120, env={**os.environ, "PYTHONPATH": os.getcwd()},
    )
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.count("\n") == 1 and "FIFO" in proc.stderr and "Traceback" not in proc.stderr


def test_size_limit(tmp_path, capsys):
    path = _write(tmp_path, "# " + "x" * SCENE_LIMIT + "\n")
    line = _cli_error(capsys, ["sim", path, "--quiet"])
    assert "limit" in line and str(SCENE_LIMIT) in line


def test_not_utf8(tmp_path, capsys):
    path = _write(tmp_path, b"name: caf\xe9\nduration: 1\n")
    line = _cli_error(capsys, ["sim", path, "--quiet"])
    assert "not UTF-8" in line and "byte 9" in line


def test_read_text_reads_at_most_the_limit(tmp_path):
    path = tmp_path / "t.csv"
    path.write_text("0,1\n" * 100)
    assert read_text(path, limit=400) == "0,1\n" * 100
    with pytest.raises(InputError, match="limit of 399 bytes"):
        read_text(path, limit=399)


# ------------------------------------------------------------------ YAML
def test_alias_bomb_is_refused_with_a_short_message(tmp_path, capsys):
    bomb = ["a: &a [x, x, x, x, x, x, x, x, x]"]
    for k in range(1, 9):
        bomb.append(f"{chr(97 + k)}: &{chr(97 + k)} [" + ", ".join([f"*{chr(96 + k)}"] * 9) + "]")
    text = "\n".join(bomb) + "\nparams: {k: *i}\n"
    with pytest.raises(InputError, match="anchors") as info:
        parse_yaml(text)
    assert len(str(info.value)) < 200
    line = _cli_error(capsys, ["sim", _write(tmp_path, text), "--quiet"])
    assert len(line) < 300


def test_alias_without_anchor_in_scope_and_merge_keys(tmp_path):
    with pytest.raises(InputError, match="alias|anchor"):
        parse_yaml("dt: &d 0.001\nduration: *d\n")
    with pytest.raises(InputError):
        parse_yaml("base: &b {x: 1}\nother:\n  <<: *b\n")


@pytest.mark.parametrize("text", ["[" * 5000 + "]" * 5000, "{a: " * 3000 + "1" + "}" * 3000,
                                  "".join(f"{' ' * (2 * i)}k{i}:\n" for i in range(200)) + " " * 400 + "x"])
def test_deep_nesting_is_refused_not_a_recursion_error(tmp_path, capsys, text):
    with pytest.raises(InputError, match=f"deeper than {MAX_DEPTH}"):
        parse_yaml(text)
    _cli_error(capsys, ["sim", _write(tmp_path, text), "--quiet"])


def test_nesting_of_a_real_scene_is_allowed():
    assert parse_yaml("a:\n" + "".join(f"{' ' * (2 * i)}b{i}:\n" for i in range(1, MAX_DEPTH - 1)) + " " * 2 * (MAX_DEPTH - 1) + "1\n")


def test_duplicate_keys_are_an_error(tmp_path, capsys):
    text = yaml.safe_dump(_paper_dict(), sort_keys=False) + "dt: 0.001\n"
    line = _cli_error(capsys, ["sim", _write(tmp_path, text), "--quiet"])
    assert "duplicate key 'dt'" in line and "first on line" in line
    with pytest.raises(InputError, match="duplicate key 'k'"):
        parse_yaml("params:\n  k: 1.0\n  k: 2.0\n")


def test_yaml_12_numbers():
    data = parse_yaml("a: 2.0e4\nb: 1e1\nc: -3E-2\nd: '2e4'\ne: 5\nf: 1.5\n")
    assert data == {"a": 2.0e4, "b": 10.0, "c": -0.03, "d": "2e4", "e": 5, "f": 1.5}
    assert isinstance(data["b"], float) and isinstance(data["e"], int)


# ------------------------------------------------------------------ required keys
@pytest.mark.parametrize("key", ["params", "drive", "load", "duration", "dt"])
def test_required_keys(tmp_path, capsys, key):
    data = _paper_dict()
    del data[key]
    line = _cli_error(capsys, ["sim", _write(tmp_path, data), "--quiet"])
    assert f"missing required key '{key}'" in line and "extends" in line


def test_every_parameter_is_required(tmp_path, capsys):
    """Dropping only I_M used to run with the default 1 kg m^2 (final speed 5.7 instead of 110.7 rad/s)."""
    data = _paper_dict()
    del data["params"]["I_M"]
    line = _cli_error(capsys, ["sim", _write(tmp_path, data), "--quiet"])
    assert line.startswith("belt-drive: error: I_M: missing")


def test_optional_belt_fields_stay_optional():
    data = _paper_dict()
    assert "groove_angle" not in data["params"] and "belt_mass" not in data["params"]
    assert Scene.from_mapping(data) == load_scene("paper")


def test_extends_a_shipped_scene(tmp_path):
    path = _write(tmp_path, "extends: paper\nduration: 0.5\nparams: {c: 3.0}\n", name="short_paper.yaml")
    scene = load_scene(path)
    paper = load_scene("paper")
    assert scene.name == "short_paper" and scene.duration == 0.5
    assert scene.params == paper.params.replace(c=3.0)
    assert scene.drive == paper.drive and scene.dt == paper.dt and scene.method == paper.method
    same = load_scene(_write(tmp_path, "extends: paper\n", name="same.yaml"))
    assert simulate(same).outputs["omega_M"][-1] == simulate(paper).outputs["omega_M"][-1]
    with pytest.raises(SceneError, match="extends: must name a shipped scene"):
        load_scene(_write(tmp_path, "extends: /etc/passwd\n"))


# ------------------------------------------------------------------ types and ranges
@pytest.mark.parametrize(
    "change, named",
    [
        ({"params": {"k": "20000.0"}}, "k"),
        ({"drive": {"type": "motor", "stall_torque": "12", "no_load_speed": 160.0, "soft_start_time": 0.02}}, "drive.stall_torque"),
        ({"duration": "5"}, "duration"),
        ({"initial_state": {"omega_M": "1"}}, "initial_state.omega_M"),
        ({"method_options": {"rtol": "0.001"}}, "method_options.rtol"),
        ({"load": {"type": "polynomial", "c0": 0.0, "c1": ["0.02"], "c2": 0.0}}, "load.c1"),
    ],
)
def test_numbers_are_numbers(tmp_path, capsys, change, named):
    data = _paper_dict()
    for key, value in change.items():
        data[key] = {**data[key], **value} if key == "params" else value
    line = _cli_error(capsys, ["sim", _write(tmp_path, data), "--quiet"])
    assert named in line and ("number" in line or "got" in line)


def test_quoted_exponent_is_a_string_not_a_number(tmp_path, capsys):
    """The issue's case: ``k: '2e4'`` was taken as 20000 N/m."""
    text = yaml.safe_dump(_paper_dict(), sort_keys=False).replace("k: 20000.0", "k: '2e4'")
    assert "k: '2e4'" in text
    line = _cli_error(capsys, ["sim", _write(tmp_path, text), "--quiet"])
    assert "k: must be a number, got str '2e4'" in line


@pytest.mark.parametrize(
    "key, value, word",
    [("dt", 1e-300, "plausible range"), ("output_rate", 1e12, "plausible range"),
     ("duration", 1e9, "plausible range"), ("duration", 1e300, "plausible range")],
)
def test_absurd_scene_values(tmp_path, capsys, key, value, word):
    data = {**_paper_dict(), key: value}
    line = _cli_error(capsys, ["sim", _write(tmp_path, data), "--quiet"])
    low, high, unit = RANGES[key]
    assert line.startswith(f"belt-drive: error: {key}:") and word in line and f"{high:g}" in line


def test_absurd_parameter_value(tmp_path, capsys):
    data = _paper_dict()
    data["params"]["k"] = 1e300
    line = _cli_error(capsys, ["sim", _write(tmp_path, data), "--quiet"])
    assert "k:" in line and "plausible range" in line and "1e+10" in line


@pytest.mark.parametrize("params", ["stiff", [1.0, 2.0], 3.0])
def test_params_not_a_mapping(tmp_path, capsys, params):
    line = _cli_error(capsys, ["sim", _write(tmp_path, {**_paper_dict(), "params": params}), "--quiet"])
    assert "params" in line and "mapping" in line


def test_method_options_not_a_mapping(tmp_path, capsys):
    line = _cli_error(capsys, ["sim", _write(tmp_path, {**_paper_dict(), "method_options": [1, 2]}), "--quiet"])
    assert "method_options" in line and "mapping" in line


def test_huge_value_is_quoted_short(tmp_path, capsys):
    data = _paper_dict()
    data["params"]["k"] = "9" * 500_000
    line = _cli_error(capsys, ["sim", _write(tmp_path, data), "--quiet"])
    assert len(line) < 300 and "truncated" in line


def test_short():
    assert short("abc") == "'abc'"
    assert len(short("x" * 10**6)) < 120
    assert short(list(range(1000))) == "<list of 1000 items>"


def test_csv_profile_goes_through_the_loader(tmp_path):
    from belt_drive_ros.commands.source import read_csv_profile

    with pytest.raises(InputError, match="character device"):
        read_csv_profile("/dev/zero")
    bad = tmp_path / "p.csv"
    bad.write_bytes(b"time,drive_torque\n0,\xff\n")
    with pytest.raises(InputError, match="not UTF-8"):
        read_csv_profile(bad)


def test_node_scene_parameter_uses_the_loader():
    from belt_drive_ros.ros.parameter_schema import NodeConfigError, SceneCache

    with pytest.raises(NodeConfigError, match="character device"):
        SceneCache().get("/dev/zero")


def test_shipped_scenes_and_bag_scenes_load_strictly():
    from pathlib import Path

    for path in sorted(Path(__file__).resolve().parents[1].joinpath("bags").glob("*.yaml")):
        assert load_scene(path).duration > 0
    with pytest.raises(ParameterError):
        Scene.from_mapping({**_paper_dict(), "params": {"k": 1.0}})


def test_typed_values_name_the_key():
    """The checks campaign files (and any caller) use: text is not a number nor a boolean, a boolean is not a
    number, 2.7 is not a count (refused, never truncated), 1e3 is; .inf and .nan are not finite."""
    from belt_drive_ros.campaign.values import boolean, mapping, number, sequence, text

    assert number(1.5e4, "k") == 1.5e4 and number(parse_yaml("n: 1.5e4")["n"], "n") == 15000.0
    count = number(parse_yaml("n: 1e3")["n"], "n", integer=True, low=1)
    assert count == 1000 and isinstance(count, int)
    for value, word in (("12", "a whole number"), (True, "a whole number"), (2.7, "a whole number"),
                        (float("inf"), "a finite number"), ([1], "a whole number")):
        with pytest.raises(InputError, match=f"monte_carlo.samples: must be {word}, got"):
            number(value, "monte_carlo.samples", integer=True)
    with pytest.raises(InputError, match=r"seed: -1 is outside \[0, inf\]"):
        number(-1, "seed", low=0, integer=True)
    with pytest.raises(InputError, match="a finite number"):
        number(float("nan"), "x")
    assert boolean(False, "absolute") is False
    for value in ("false", 0, None):
        with pytest.raises(InputError, match="absolute: must be true or false"):
            boolean(value, "absolute")
    assert mapping(None, "grid", empty={}) == {} and sequence((1,), "v") == [1] and text("a", "name") == "a"
    with pytest.raises(InputError, match="grid: must be a mapping"):
        mapping([1], "grid", empty={})
    with pytest.raises(InputError, match=r"grid.k: must be a non-empty list, got \[\]"):
        sequence([], "grid.k", nonempty=True)
    with pytest.raises(InputError, match="name: must be a string"):
        text(5, "name")


def test_an_extended_scene_with_its_own_torques_gets_the_method_chosen_for_them(tmp_path):
    """Review of issue 22: 'extends: paper' with a sine drive at the belt mode inherited paper's lawson5 (chosen for
    paper's soft start), so the automatic choice never ran and the run was INACCURATE; new torques without a stated
    method get method: auto at the inherited dt. A stated method, or a change of parameters only, keeps what is given."""
    paper = load_scene("paper")
    sine = "drive: {type: sine, mean: 5.0, amplitude: 10.0, frequency: 10.5}\n"
    scene = load_scene(_write(tmp_path, "extends: paper\n" + sine, name="sine.yaml"))
    assert scene.method == "auto" and scene.dt == paper.dt and scene.method_options == {}
    result = simulate(scene.with_overrides(duration=1.0))
    assert result.method_choice is not None and result.method != "auto"  # a real method, chosen and said why
    stated = load_scene(_write(tmp_path, "extends: paper\nmethod: etd2\n" + sine, name="stated.yaml"))
    assert stated.method == "etd2"
    load_only = load_scene(_write(tmp_path, "extends: truck_compressor\nload: 1.0\n", name="load.yaml"))
    assert load_only.method == "auto"
    params_only = load_scene(_write(tmp_path, "extends: paper\nparams: {c: 3.0}\n", name="c.yaml"))
    assert params_only.method == paper.method


@pytest.mark.parametrize("digits", [20, 4300, 5000, 100_000], ids=["20", "4300", "5000", "100000"])
def test_integers_of_any_length_in_yaml_are_one_input_error(digits, tmp_path, capsys):
    """An integer past 2^63 is refused naming its line, however long (before: past Python's 4300-digit
    limit of int-from-text, an internal ValueError, exit 1)."""
    text = f"extends: paper\nparams:\n  k: {'9' * digits}\n"
    with pytest.raises(InputError, match="line 3: integer .* is too large"):
        parse_yaml(text)
    path = tmp_path / "big.yaml"
    path.write_text(text)
    line = _cli_error(capsys, ["sim", str(path), "--quiet"])
    assert "line 3: integer" in line and "too large" in line


def test_yaml_numbers_booleans_and_null_follow_the_yaml_1_2_core_schema(tmp_path, capsys):
    """PyYAML's SafeLoader reads YAML 1.1: ``F_0: 0400`` loaded as 256 N (octal), ``duration: 1:30`` as 90 s
    (sexagesimal), ``20_000`` as 20000 and ``yes`` as True, silently. The docs promise YAML 1.2: 0400 is the decimal
    400, 0o/0x are octal and hexadecimal, ``1:30``, ``20_000`` and ``yes`` are strings (then named as not a number)."""
    from belt_drive_ros.cli import main

    data = parse_yaml("a: 0400\nb: 1:30\nc: 20_000\nd: 0o17\ne: 0x1F\nf: yes\ng: true\nh: ~\ni: .inf\nj: -.Inf\n"
                      "k: .5\nl: +3\nm: 2026-01-01\nn: False\no:\n")
    assert data == {"a": 400, "b": "1:30", "c": "20_000", "d": 15, "e": 31, "f": "yes", "g": True, "h": None,
                    "i": math.inf, "j": -math.inf, "k": 0.5, "l": 3, "m": "2026-01-01", "n": False, "o": None}
    assert math.isnan(parse_yaml("x: .nan")["x"]) and type(parse_yaml("x: 0400")["x"]) is int
    scene = tmp_path / "s.yaml"
    scene.write_text("extends: paper\nduration: 1:30\n")
    assert main(["sim", str(scene)]) == 2
    assert "duration" in capsys.readouterr().err
    scene.write_text("extends: paper\nduration: 0.05\nparams: {F_0: 0400}\n")
    from belt_drive_ros.io.scenes import load_scene

    assert load_scene(scene).params.F_0 == 400.0


def test_yaml_merge_keys_stay_refused_under_the_yaml_1_2_resolvers():
    """The YAML 1.2 resolver table first dropped PyYAML's merge resolver: '<<' became a plain key, and a params file
    with one passed the check (rcl then ignored it silently)."""
    with pytest.raises(Exception, match=r"line 2: YAML merge keys \(<<\) are not allowed"):
        parse_yaml("a:\n  <<: {k: 1}\n")
