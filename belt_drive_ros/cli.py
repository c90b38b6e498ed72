"""``belt-drive``: command-line entry point.

Each subcommand lives in its own module under :mod:`belt_drive_ros.commands`
with ``register(subparsers)``; modules must not import rclpy or mcap at
import time (only inside their run function), so ``belt-drive --help`` and
``belt-drive sim`` work without ROS.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import os
import signal
import sys

from .core.errors import BeltDriveError, OutputError, SimulationDivergedError

#: subcommand modules, in --help order. A module missing here is skipped silently
#: only if it does not exist yet (commands under construction).
COMMAND_MODULES = (
    "sim",
    "sweep",
    "scenes",
    "modes",
    "demo",
    "node",
    "source",
    "record",
    "replay",
    "bench",
    "make_bags",
    "urdf",
)


#: commands without a ROS context: SIGTERM raises (io.atomic.Terminated) so that an output in progress is removed
OFFLINE_COMMANDS = frozenset({"sim", "sweep", "scenes", "modes", "make-bags", "urdf"})


class _Parser(argparse.ArgumentParser):
    """argparse with its refusals (a bad option value, a missing argument) as one ``belt-drive: error:`` line naming
    the subcommand, exit 2, instead of the usage block before it; subcommands' parsers are of this class too."""

    def error(self, message):
        command = self.prog.partition(" ")[2]
        sys.exit(_fail(f"{command + ': ' if command else ''}{message} (see '{self.prog} --help')", 2))


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="belt-drive",
        description=(
            "Vehicle accessory belt drive (engine/motor -> two gear pairs -> belt -> loaded pulley): "
            "offline simulation, ROS 2 node, torque sources, MCAP recording and replay, benchmarks. "
            "SI units everywhere (rad, rad/s, N m, s); rpm only in plots and summaries."
        ),
        epilog="Run 'belt-drive COMMAND --help' for each command's options and examples.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMAND_MODULES:
        try:
            module = importlib.import_module(f"belt_drive_ros.commands.{name}")
        except ModuleNotFoundError as exc:
            if exc.name == f"belt_drive_ros.commands.{name}":
                continue
            raise
        module.register(sub)
    return parser


#: the parser :func:`main` uses, built on its first call (every command module imported and registered: ~30 ms, and
#: ~100 ms on a loaded machine; a process calling main() many times, the tests and ``bench hostile``, builds it once)
_PARSER: list = []


def _parser() -> argparse.ArgumentParser:
    if not _PARSER:
        _PARSER.append(build_parser())
    return _PARSER[0]


def _one_line_warning(message, category, filename, lineno, file=None, line=None):
    print(f"belt-drive: warning: {message}", file=file or sys.stderr)


def _stdout_gone() -> bool:
    """Whether standard output's reader has gone (its pipe broken); if so, stdout points at /dev/null from now on
    (the interpreter's flush at exit would meet the broken pipe again and print about it)."""
    import select

    try:
        fd = sys.stdout.fileno()
        poll = select.poll()
        poll.register(fd, select.POLLOUT)
        gone = any(event & select.POLLERR for _, event in poll.poll(0))  # (a pipe without a reader: POLLERR)
    except (OSError, ValueError, AttributeError):
        return False
    if gone:
        with contextlib.suppress(OSError, ValueError):
            os.dup2(os.open(os.devnull, os.O_WRONLY), fd)
    return gone


def main(argv: list[str] | None = None) -> int:
    import warnings

    warnings.showwarning = _one_line_warning  # e.g. a truncated bag: say so in one line
    if argv is None and sys.stderr is None:  # (a program started with stderr closed, `2>&-`: print(file=None)
        sys.stderr = open(os.devnull, "w")  # writes to stdout; its errors and warnings go nowhere, as any tool's)
    try:  # (~0.3 s of imports: a SIGINT here ends as one during the run does, never with a traceback)
        parser = _parser()
        args = parser.parse_args(argv)
        if not getattr(args, "func", None):
            parser.print_help()
            return 2
        from .io.atomic import CLEANUP_LIMIT, Terminated, terminate_raises

        # (a program: an interrupted run's cleanup is bounded; a caller's own process is never ended. Not a
        # campaign's: it may act on a signal its gc callback swallowed only when the batch running ends, which
        # can take minutes, and it closes its cluster itself; ended by a watchdog, its workers would be orphaned)
        bounded = argv is None and args.command != "sweep"
        on_term = (terminate_raises(CLEANUP_LIMIT if bounded else None) if args.command in OFFLINE_COMMANDS
                   else contextlib.nullcontext())
    except KeyboardInterrupt:
        return _interrupted(signal.SIGINT, argv, "")
    try:
        with on_term:
            code = int(args.func(args) or 0)
        if argv is None and args.command in QUICK_EXIT_COMMANDS:
            _exit_now(code)
        return code
    except (SimulationDivergedError, OutputError) as exc:
        return _fail(exc, 1)  # a failed run or a failed write, not bad input
    except BeltDriveError as exc:
        return _fail(exc, 2) if not isinstance(exc, OSError) or isinstance(exc, FileExistsError) else _fail(exc, 1)
    except (FileNotFoundError, PermissionError, IsADirectoryError, NotADirectoryError, UnicodeError) as exc:
        return _fail(exc, 2)  # an input that cannot be read as given
    except RecursionError:
        return _fail("input nested too deeply", 2)
    except KeyboardInterrupt as exc:  # SIGINT, or SIGTERM as Terminated: outputs in progress were removed
        return _interrupted(exc.signum if isinstance(exc, Terminated) else signal.SIGINT, argv,
                            _after_interruption(args.command in OFFLINE_COMMANDS))
    except MemoryError:
        return _fail("out of memory (a shorter run, or --out to stream it, needs less)", 1)
    except BrokenPipeError as exc:
        if not _stdout_gone():  # another pipe: a failed run
            return _fail(exc, 1)
        return 128 + signal.SIGPIPE  # stdout's reader left (`| head`): nothing more to say, the status a shell gives
    except OSError as exc:  # disk full, I/O error: the run failed, the input was fine
        return _fail(exc, 1)
    except Exception as exc:  # noqa: BLE001 - one line, never a traceback (BELT_DRIVE_DEBUG=1 shows it)
        if os.environ.get("BELT_DRIVE_DEBUG"):
            raise
        # rclpy's refusals of --ros-args (its exception types have no public import path)
        if type(exc).__name__ == "UnknownROSArgsError":
            return _fail(f"--ros-args: unknown ROS arguments {exc}", 2)
        if type(exc).__name__ == "RCLError" and "failed to initialize rcl" in str(exc):
            return _fail(f"--ros-args: refused by rcl: {str(exc).split(', at /')[0]}", 2)
        if type(exc).__name__ in ("InvalidParameterTypeException", "InvalidParameterValueException"):
            # a parameter rclpy itself declares (use_sim_time) or checks at the node's start (-p scene:=5)
            name = getattr(exc, "parameter_name", None) or str(exc).rsplit(": ", 1)[-1]
            return _fail(f"{name}: wrong {'type' if 'Type' in type(exc).__name__ else 'value'}: "
                         f"{str(exc).removesuffix(f': {name}')}", 2)
        return _fail(f"internal error: {type(exc).__name__}: {exc} (BELT_DRIVE_DEBUG=1 shows the traceback)", 1)


#: ROS commands that, run as a program, end the process as soon as they have stopped cleanly (nodes
#: destroyed, recordings finished, rclpy shut down: Fast DDS has released its shared memory by then).
#: The interpreter's own teardown of numpy, scipy and rclpy adds ~0.2 s idle and 1-2 s on a loaded
#: machine between SIGINT/SIGTERM and the exit, for nothing left to do.
QUICK_EXIT_COMMANDS = frozenset({"node", "record", "source", "replay"})


def _interrupted(signum: int, argv, detail: str) -> int:
    """Say in one line that signal ``signum`` interrupted the command (``detail`` after its name); 128 + ``signum``."""
    print(f"belt-drive: interrupted by {signal.Signals(signum).name}{detail}", file=sys.stderr)
    if argv is None:
        # a program: end now. Its daemon threads (the accuracy guard, the MCAP writer) may still be inside
        # compiled code; the interpreter's teardown around them once ended a SIGTERM'd `sim --bag-folder` with
        # "terminate called without an active exception" and SIGABRT after the outputs were already removed
        _exit_now(128 + int(signum))
    return 128 + int(signum)


def _after_interruption(in_block: bool) -> str:
    """What an interrupted command left: the outputs it had committed are complete and kept (``--out`` written,
    then interrupted while its ``--plot`` or summary was made); anything unfinished was removed.

    ``in_block``: the command ran in a :func:`~belt_drive_ros.io.atomic.terminate_raises` block (an offline
    command), whose commits :func:`~belt_drive_ros.io.atomic.committed_outputs` lists. Any other command notes none,
    and that list is then the last block's: an earlier command's of the same process (``cli.main`` called again),
    not this one's."""
    from .io.atomic import committed_outputs

    kept = committed_outputs() if in_block else []
    return (f"; kept, complete: {', '.join(kept)}; " if kept else "; ") + "unfinished outputs removed"


def _exit_now(code: int) -> None:
    """Flush stdout and stderr, then end the process with ``code`` without the interpreter's teardown."""
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    os._exit(code)


#: longest error line [characters]; messages quote values short, this only guards the rest
MESSAGE_LIMIT = 400


def _fail(exc, code: int) -> int:
    """Print ``exc`` as one ``belt-drive: error:`` line (at most :data:`MESSAGE_LIMIT` characters); return ``code``."""
    text = " ".join(str(exc).split()) or type(exc).__name__
    if len(text) > MESSAGE_LIMIT:
        text = text[:MESSAGE_LIMIT] + "..."
    print(f"belt-drive: error: {text}", file=sys.stderr)
    return code

if __name__ == "__main__":
    sys.exit(main())
