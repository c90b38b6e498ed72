"""Regularised friction as a selectable model, its stability guard, and methods the slipping model refuses."""

from __future__ import annotations

from belt_drive_ros.cli import main


def _one_line_error(err: str) -> str:
    lines = [ln for ln in err.strip().splitlines() if ln.strip()]
    assert len(lines) == 1, err
    assert "Traceback" not in err and lines[0].startswith("belt-drive: error:")
    return lines[0]


def test_symplectic_euler_on_the_slipping_model_is_a_one_line_refusal(capsys):
    # the slip mode relaxes the span stretch by a first-order equation: no [coordinates, speeds] split
    code = main(["sim", "truck_compressor", "--model", "slipping", "--method", "symplectic_euler", "--duration", "0.05", "--quiet"])
    line = _one_line_error(capsys.readouterr().err)
    assert code == 2
    assert "symplectic_euler" in line and "etd2" in line and "internal error" not in line
    # the flexible model keeps the method (a meaningful run of the same scene)
    code = main(["sim", "truck_compressor", "--model", "flexible", "--method", "symplectic_euler", "--dt", "1e-4",
                 "--duration", "0.05", "--quiet"])  # fmt: skip
    assert code == 0, capsys.readouterr().err
