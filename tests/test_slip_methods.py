"""Methods the slipping model refuses, and the removed regularised model named in a one-line error."""

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



def test_auto_with_symplectic_euler_runs_a_scene_within_the_limit_on_the_linear_model():
    # auto's single slipping pass cannot take a [coordinates, speeds] method: such a method keeps the
    # two-run path, so a scene that never reaches the capstan limit runs exactly as on its linear model
    from belt_drive_ros.io.scenes import load_scene
    from belt_drive_ros.core.simulate import simulate
    import numpy as np

    scene = load_scene("paper")
    auto = simulate(scene, method="symplectic_euler", dt=1e-3)
    assert auto.choice.model == "flexible"
    linear = simulate(scene, model="flexible", method="symplectic_euler", dt=1e-3)
    assert np.array_equal(auto.states, linear.states)
    assert auto.outputs.keys() == linear.outputs.keys()
    assert all(np.array_equal(auto.outputs[k], linear.outputs[k]) for k in auto.outputs)


def test_auto_with_symplectic_euler_on_a_slipping_scene_is_a_one_line_refusal(capsys):
    # truck_compressor reaches the capstan limit at ~0.5 s: the slipping model is needed and refuses the method
    code = main(["sim", "truck_compressor", "--method", "symplectic_euler", "--duration", "1", "--quiet"])
    line = _one_line_error(capsys.readouterr().err)
    assert code == 2 and "symplectic_euler" in line and "slipping" in line


def test_the_regularised_model_is_gone_and_named_in_a_one_line_error(tmp_path, capsys):
    # the event-located stick/slip hybrid (model slipping) replaced it: a scene naming it is refused
    path = tmp_path / "reg.yaml"
    path.write_text("extends: truck_compressor\nmodel: regularised\nduration: 0.05\n")
    code = main(["sim", str(path), "--quiet"])
    line = _one_line_error(capsys.readouterr().err)
    assert code == 2 and "regularised" in line and "slipping" in line
