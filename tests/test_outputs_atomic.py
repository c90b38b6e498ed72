"""Outputs of msg-tools export/plot and belt-drive make-bags appear whole or not at all (issue 13):
an existing file is kept without ``--force``, a failed write (a full disk, simulated where
the data is flushed to disk) leaves neither the output nor a temporary file, a device such as
/dev/full or a wrong extension is refused up front in one line."""

from __future__ import annotations

import errno
import os

import numpy as np
import pytest

from msg_tools import Ros2McapWriter
from msg_tools.cli import main as msg_tools


@pytest.fixture
def bag(tmp_path):
    path = tmp_path / "run.mcap"
    with Ros2McapWriter(path) as w:
        for i in range(200):
            w.write("/drive_torque", "std_msgs/msg/Float64", {"data": float(np.sin(i / 10))}, 10**9 + i * 10**6)
    return path


def _cli(capsys, *argv):
    status = msg_tools([str(a) for a in argv])
    out, err = capsys.readouterr()
    return status, out, err


def _one_line(err: str, expected: str) -> None:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("msg-tools: error: ") and expected in lines[0], err


def _disk_full(*_args, **_kwargs):
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


@pytest.mark.parametrize("verb,name", [("export", "out.csv"), ("plot", "out.png")])
def test_existing_output_is_kept_without_force_and_replaced_with_it(capsys, tmp_path, bag, verb, name):
    target = tmp_path / name
    target.write_bytes(b"keep me")
    extra = ["--topic", "/drive_torque"] if verb == "export" else []
    status, _, err = _cli(capsys, verb, bag, *extra, "--out", target)
    assert status == 2
    _one_line(err, "exists; pass --force")
    assert err.strip().endswith(f"{target} exists; pass --force to overwrite it"), err  # the one sentence
    assert target.read_bytes() == b"keep me"
    status, _, err = _cli(capsys, verb, bag, *extra, "--out", target, "--force")
    assert status == 0, err
    assert target.read_bytes() != b"keep me" and target.stat().st_size > 100
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["run.mcap", name])


@pytest.mark.parametrize("verb,name", [("export", "out.csv"), ("plot", "out.png")])
def test_a_failed_write_leaves_nothing_behind(capsys, tmp_path, bag, verb, name, monkeypatch):
    extra = ["--topic", "/drive_torque"] if verb == "export" else []
    monkeypatch.setattr(os, "fsync", _disk_full)  # the data reaches the disk at fsync: full
    status, _, err = _cli(capsys, verb, bag, *extra, "--out", tmp_path / name)
    assert status == 2
    _one_line(err, "No space left on device")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.mcap"]  # no output, no .part file


@pytest.mark.parametrize("argv,expected", [
    (["export", "{bag}", "--topic", "/drive_torque", "--out", "/dev/full"], "not a regular file"),
    (["plot", "{bag}", "--out", "/dev/full"], "must be a .png file"),
    (["plot", "{bag}", "--out", "{tmp}/x.csv"], "must be a .png file"),
    (["plot", "{bag}", "--out", "{tmp}"], "must be a .png file"),
    (["export", "{bag}", "--topic", "/drive_torque", "--out", "{tmp}"], "not a regular file"),
])
def test_bad_outputs_are_refused_up_front(capsys, tmp_path, bag, argv, expected):
    status, _, err = _cli(capsys, *[a.format(bag=bag, tmp=tmp_path) for a in argv])
    assert status == 2
    _one_line(err, expected)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.mcap"]


def test_make_bags_leaves_no_partial_file_and_keeps_existing_ones(tmp_path, monkeypatch, capsys):
    from belt_drive_ros.cli import main
    from belt_drive_ros.io import recording

    real = recording.write_result_mcap
    calls = []

    def fails_on_the_golden(result, path, *args, **kwargs):
        calls.append(path)
        if len(calls) == 2:  # the golden bag: half written, then the disk is full
            path.write(b"\x89MCAP0\r\n" + b"x" * 1000)
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return real(result, path, *args, **kwargs)

    monkeypatch.setattr(recording, "write_result_mcap", fails_on_the_golden)
    assert main(["make-bags", "--out", str(tmp_path), "--only", "engine_idle"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "No space left on device" in err[0] and "nothing written" in err[0], err
    names = sorted(p.name for p in tmp_path.iterdir())
    assert names == ["engine_idle.yaml", "engine_idle_torque.mcap"], names  # no golden, no .part
    monkeypatch.setattr(recording, "write_result_mcap", real)
    before = (tmp_path / "engine_idle.yaml").read_bytes()
    assert main(["make-bags", "--out", str(tmp_path), "--only", "engine_idle"]) == 2  # exists: refused
    assert capsys.readouterr().err.strip().endswith(f"{tmp_path / 'engine_idle.yaml'} exists (and 1 more file(s) it "
                                                    "would write); pass --force to overwrite it")
    assert (tmp_path / "engine_idle.yaml").read_bytes() == before
    assert main(["make-bags", "--out", str(tmp_path), "--only", "engine_idle", "--force"]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["engine_idle.yaml", "engine_idle_golden.mcap",
                                                          "engine_idle_torque.mcap"]
