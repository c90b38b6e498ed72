"""An interruption after a command has committed an output says that output is kept, complete.

``belt-drive sim --out RUN --plot FIG`` writes RUN, then runs the overlay and writes FIG: a SIGINT or SIGTERM in
between removes the unfinished figure, but RUN is whole and stays. The one-line message used to say only
"unfinished outputs removed", which read as if RUN had gone too.
"""

from __future__ import annotations

import pytest

from belt_drive_ros import cli
from belt_drive_ros.commands import sim as sim_command
from belt_drive_ros.io.atomic import Terminated, committed_outputs, note_committed


def _interrupt(exc):
    def write_plot(*args, **kwargs):
        raise exc

    return write_plot


@pytest.mark.parametrize("exc, code, name", [(KeyboardInterrupt(), 130, "SIGINT"), (Terminated(), 143, "SIGTERM")])
@pytest.mark.parametrize("out", ["run.mcap", "run.csv", "bag"])
def test_an_output_written_before_the_interruption_is_named_as_kept(tmp_path, monkeypatch, capsys, exc, code, name, out):
    target, plot = tmp_path / out, tmp_path / "fig.png"
    monkeypatch.setattr(sim_command, "_write_plot", _interrupt(exc))
    argv = ["sim", "paper", "--duration", "0.05", "--quiet", "--out", str(target), "--plot", str(plot)]
    assert cli.main(argv + (["--bag-folder"] if out == "bag" else [])) == code
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"belt-drive: interrupted by {name}; kept, complete: {target}; unfinished outputs removed"]
    assert target.exists() and not plot.exists()
    if out == "bag":
        assert any(p.suffix == ".mcap" for p in target.iterdir()) and (target / "metadata.yaml").is_file()
    else:
        assert target.stat().st_size > 0


def test_an_interruption_before_any_commit_names_nothing_as_kept(tmp_path, monkeypatch, capsys):
    target = tmp_path / "run.mcap"

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(sim_command, "print_summary", interrupted)  # (before the output is written)
    assert cli.main(["sim", "paper", "--duration", "0.05", "--out", str(target)]) == 130
    assert capsys.readouterr().err.strip().splitlines() == ["belt-drive: interrupted by SIGINT; unfinished outputs removed"]
    assert not target.exists() and committed_outputs() == []


def test_commits_outside_a_block_are_not_noted(tmp_path):
    note_committed(tmp_path / "x")  # (a library caller's output, no command running)
    assert str(tmp_path / "x") not in committed_outputs()


def test_an_interrupted_command_without_a_block_names_no_earlier_command_s_output(tmp_path, monkeypatch, capsys):
    """A caller running commands in one process (``cli.main(argv)``): an output an earlier command committed is not
    this command's. A command that runs outside :func:`~belt_drive_ros.io.atomic.terminate_raises` (``bench``,
    ``node``, ``record``, ...) and is interrupted used to say "kept, complete: <the earlier command's output>"."""
    import argparse

    target = tmp_path / "run.mcap"
    assert cli.main(["sim", "paper", "--duration", "0.05", "--quiet", "--out", str(target)]) == 0
    assert committed_outputs() == [str(target)]  # (the finished block's record stays readable)

    def interrupted(args):
        raise KeyboardInterrupt

    class _Parsed:
        def parse_args(self, argv):
            return argparse.Namespace(command="bench", func=interrupted)

    monkeypatch.setattr(cli, "_parser", lambda: _Parsed())
    assert "bench" not in cli.OFFLINE_COMMANDS
    assert cli.main(["bench"]) == 130
    assert capsys.readouterr().err.strip().splitlines() == ["belt-drive: interrupted by SIGINT; unfinished outputs removed"]
