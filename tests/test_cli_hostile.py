"""Bad command-line input: one ``belt-drive: error:`` line naming what is wrong and exit 2, before anything runs."""

from __future__ import annotations

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
        "replay --rate 0": (["replay", str(a_file), "--rate", "0"], "--rate: must be finite and > 0"),
        "replay --rate inf": (["replay", str(a_file), "--rate", "inf"], "--rate: must be finite and > 0"),
        "replay --sync without --clock": (["replay", str(a_file), "--sync", "/joint_states"], "--sync: needs --clock"),
        "replay --delay -1": (["replay", str(a_file), "--delay", "-1"], "--delay: must be finite and >= 0 s"),
        "modes same PNG twice": (["modes", "fead_i4", "--campbell", str(tmp / "a.png"), "--runup", str(tmp / "a.png")],
                                 "--campbell and --runup name the same file"),
    }


CASES = [
    "record --duration -1", "record --duration nan", "demo --duration -1", "demo --duration inf", "demo --out-dir a file",
    "make-bags --out a file", "make-bags --out /dev/null", "modes --campbell x.txt", "modes --runup x.csv", "modes same PNG twice",
    "sim --bag-folder in a missing folder", "bench --minutes -1", "bench --seconds nan", "bench --samples 0", "bench --out a file",
    "urdf --out and --png the same", "network sim --tolerance",
    "replay --rate 0", "replay --rate inf", "replay --sync without --clock", "replay --delay -1",
]


@pytest.mark.parametrize("case", CASES)
def test_bad_option_values_are_one_line_and_exit_2_before_anything_runs(case, tmp_path, capsys):
    """Before: record's --duration exited 1 (a SystemExit text), make-bags into a file exited 1 with
    '[Errno 17] File exists', demo started its ROS part with a negative --duration, modes wrote a PNG into
    x.txt (every other PNG option refuses that), sim --bag-folder made the missing parents of --out (a file
    --out says the folder does not exist), bench took a negative or nan --minutes/--seconds/--samples and an
    --out naming a file failed with exit 1 ('[Errno 17] File exists'), urdf wrote the URDF and then the PNG into
    one file, a network sim took any --tolerance (even nan) and ignored it, replay's --rate 0, --sync
    without --clock and a negative --delay exited 1 (a SystemExit text)."""
    argv, message = _cases(tmp_path)[case]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("belt-drive: error: "), err
    assert re.search(message, err[0]), err
    assert not (tmp_path / "missing").exists() and not (tmp_path / "x.txt").exists() and not (tmp_path / "x.csv").exists() and not (tmp_path / "a.png").exists()
