"""A SIGINT while ``belt-drive`` is still starting (its parser built: the command modules and numpy imported,
~0.3 s of a run) ends it as one during the run does: one line, exit 130, never a traceback."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

#: a ``belt-drive`` program (``cli.main()`` without arguments, as the entry point calls it) that SIGINTs itself
#: while the parser is built: where the signal of a quick Ctrl-C lands
PROGRAM = """
import os, signal, sys
import belt_drive_ros.commands.{module} as command
from belt_drive_ros import cli

register = command.register
def interrupted_register(subparsers):
    os.kill(os.getpid(), signal.SIGINT)
    return register(subparsers)
command.register = interrupted_register
sys.argv = ["belt-drive", "sim", "paper", "--duration", "0.01"]
sys.exit(cli.main())
"""


@pytest.mark.parametrize("module", ["sim", "urdf"])  # the first command registered, and the last
def test_a_sigint_while_the_parser_is_built_ends_in_one_line_with_130(module):
    done = subprocess.run([sys.executable, "-c", PROGRAM.format(module=module)], capture_output=True, text=True,
                          timeout=120, env={**os.environ, "BELT_DRIVE_DEBUG": ""})
    assert done.returncode == 130, done.stderr[-2000:]
    assert done.stderr == "belt-drive: interrupted by SIGINT\n" and done.stdout == ""


def test_a_sigint_while_the_arguments_are_parsed_returns_130(monkeypatch, capsys):
    from belt_drive_ros import cli

    def interrupted(self, args=None, namespace=None):
        raise KeyboardInterrupt

    monkeypatch.setattr(cli._Parser, "parse_args", interrupted)
    assert cli.main(["sim", "paper"]) == 130
    assert capsys.readouterr().err == "belt-drive: interrupted by SIGINT\n"
