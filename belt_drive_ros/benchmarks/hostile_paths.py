"""Categories of ``belt-drive bench hostile`` for issue 24's node and file holes (prints figures; not a test).

* ``node setparameters``: ``scene`` values sent through the node's standard
  SetParameters service (another process's view) that the OS refuses or that
  are no file: names longer than 255 bytes without a slash, components past
  255 bytes, paths past PATH_MAX, a folder, a FIFO, devices, a socket, a link
  loop, an unreadable file; and, in-process (the wire cannot carry them),
  NUL bytes and unpaired surrogates. Clean: refused with a reason, the old
  scene kept, the node still ticking; an exception, an unanswered call or
  a node that stopped ticking is a crash or a hang.
* ``fifo read paths``: every command that reads a user's path, given a FIFO
  nobody writes to (``open()`` would block), ``/dev/zero`` and a folder:
  ``sim`` (scene, ``--torque-bag``), ``urdf``, ``scenes``, ``source profile``
  (CSV, scene), ``replay``, ``node --params-file`` and ``msg-tools
  info|export|plot|compare`` (either side). Clean: one error line, exit 2.
* ``truncated files``: a node recording and the shipped golden runs cut at
  many points through ``msg-tools info`` and ``compare`` (either side).
  ``info`` must exit 1 (INCOMPLETE or DAMAGED) when messages were lost and
  may exit 0 only when every message is there; ``compare`` must fail when
  either file lost messages, and pass when the cut one holds every sample
  of the whole one. An exit 0 on lost data is silent wrong, and so is a
  compare FAIL on a file that lost nothing.

Each runner is ``run(table, folder, quick, domain_id, tools)``, ``tools``
being :mod:`belt_drive_ros.benchmarks.hostile` (its ``Table``, ``_call``,
``_budget``, ``_classify_cli``, ``BUDGET_S``), so this module does not import it.
"""

from __future__ import annotations

import os
import socket
import warnings
from pathlib import Path

__all__ = ["EXTRA_CATEGORIES"]

ROOT = Path(__file__).resolve().parents[2]


def _hostile_paths(tmp: Path) -> dict[str, str]:
    """Paths that are no regular file or that the OS refuses, by label (created in ``tmp``)."""
    fifo = tmp / "x.fifo"
    if not fifo.exists():
        os.mkfifo(fifo)
    sock = tmp / "x.sock"
    if not sock.exists():
        s = socket.socket(socket.AF_UNIX)
        s.bind(str(sock))
        s.close()
    loop = tmp / "loop.yaml"
    if not os.path.lexists(loop):
        os.symlink(loop, loop)
    locked = tmp / "locked.yaml"
    if not locked.exists():
        locked.write_text("params: {}\n")
        locked.chmod(0)
    return {
        "FIFO": str(fifo), "socket": str(sock), "link loop": str(loop), "folder": str(tmp),
        "/dev/zero": "/dev/zero", "/dev/null": "/dev/null", "/dev/full": "/dev/full",
        "unreadable file": str(locked),
        "name of 300 characters": "a" * 300, "name of 5000 characters": "b" * 5000,
        "component of 300 bytes": str(tmp / ("c" * 300)) + ".yaml",
        "path past PATH_MAX": "/".join(["d" * 200] * 30) + ".yaml",
        "UTF-8 name of 200 characters (400 bytes)": "\u00e9" * 200 + ".yaml",
    }


# ------------------------------------------------------------------ node parameters over the service
def run_setparameters(table, tmp: Path, quick: bool, domain_id: int, tools) -> None:
    from ..ros.harness import BeltDriveHarness

    values = _hostile_paths(tmp)
    in_process = {"NUL byte": "x\x00y", "NUL byte in a path": str(tmp / "x\x00.yaml"),
                  "unpaired surrogate": "\ud800.yaml", "surrogates x300": "\udcff" * 300}
    if quick:
        values = dict(list(values.items())[::2])
    with tools._budget(600.0), BeltDriveHarness(domain_id=domain_id, input_timeout=0.0) as h:
        h.advance(0.01)
        for label, value in list(values.items()) + [(f"{k} (in-process)", v) for k, v in in_process.items()]:
            try:
                with tools._budget(tools.BUDGET_S):
                    if label.endswith("(in-process)"):
                        from rclpy.parameter import Parameter

                        result = h.node.set_parameters([Parameter("scene", value=value)])[0]
                    else:
                        result = h.set_parameters_over_the_service(scene=value)[0]
                    before = h.outputs()["time"].size
                    h.advance(0.005)
                    ticking = h.outputs()["time"].size == before + 5
                    kept = h.node.get_parameter("scene").value == "paper"
                    if result.successful or not kept or not ticking:
                        outcome = "silent wrong"
                    elif result.reason and len(result.reason) < 500:
                        outcome = "clean error"
                    else:
                        outcome = "crash"
                    note = result.reason[:160]
            except tools._Hang:
                outcome, note = "hang", ""
            except Exception as exc:  # noqa: BLE001 - an exception out of the call is a crash
                outcome, note = "crash", f"{type(exc).__name__}: {exc}"
            table.add("node setparameters", outcome, f"scene={label}", note)


# ------------------------------------------------------------------ FIFOs and devices to read commands
def run_fifo_reads(table, tmp: Path, quick: bool, domain_id: int, tools) -> None:
    from msg_tools.cli import main as msg_tools

    from ..cli import main as belt_drive

    paths = _hostile_paths(tmp)
    kinds = {k: paths[k] for k in ("FIFO", "/dev/zero", "folder", "socket", "link loop", "component of 300 bytes")}
    if quick:
        kinds = {k: kinds[k] for k in ("FIFO", "/dev/zero")}
    golden = str(ROOT / "bags" / "engine_idle_golden.mcap")
    out = tmp / "out"
    out.mkdir(exist_ok=True)
    commands = {
        "sim SCENE": (belt_drive, ["sim", "{p}", "--duration", "0.01", "--quiet"], "belt-drive: error:"),
        "sim --torque-bag": (belt_drive, ["sim", "paper", "--duration", "0.01", "--quiet", "--torque-bag", "{p}"],
                             "belt-drive: error:"),
        "urdf SCENE": (belt_drive, ["urdf", "{p}", "--out", str(out / "x.urdf")], "belt-drive: error:"),
        "scenes SCENE": (belt_drive, ["scenes", "{p}"], "belt-drive: error:"),
        "node --params-file": (belt_drive, ["node", "paper", "--ros-args", "--params-file", "{p}"], "belt-drive"),
        "source profile --csv": (belt_drive, ["source", "profile", "--csv", "{p}"], "belt-drive: error:"),
        "source profile --scene": (belt_drive, ["source", "profile", "--scene", "{p}"], "belt-drive: error:"),
        "replay": (belt_drive, ["replay", "{p}"], "belt-drive: error:"),
        "msg-tools info": (msg_tools, ["info", "{p}"], "msg-tools: error:"),
        "msg-tools export": (msg_tools, ["export", "{p}", "--topic", "/joint_states"], "msg-tools: error:"),
        "msg-tools plot": (msg_tools, ["plot", "{p}", "--out", str(out / "x.png")], "msg-tools: error:"),
        "msg-tools compare A": (msg_tools, ["compare", "{p}", golden], "msg-tools: error:"),
        "msg-tools compare B": (msg_tools, ["compare", golden, "{p}"], "msg-tools: error:"),
    }
    for name, (main, argv, prefix) in commands.items():
        for kind, path in kinds.items():
            if kind == "folder" and name.startswith("msg-tools"):
                continue  # a folder is a bag folder there (c24's fleet and bag-folder suite)
            status, _, err = tools._call(main, [a.replace("{p}", path) for a in argv])
            outcome = tools._classify_cli(status, err, prefix, must_fail=True)
            if outcome == "clean error" and status != 2:
                outcome = "crash"  # bad input is exit 2
            table.add("fifo read paths", outcome, f"{name} {kind}", err)


# ------------------------------------------------------------------ truncated files
def _recording(tmp: Path) -> Path:
    """A short recording of the node's topics, as the node writes them (offline writer, same layout)."""
    from ..io.scenes import load_scene
    from ..core.simulate import simulate
    from ..io.recording import write_result_mcap

    path = tmp / "run.mcap"
    if not path.exists():
        write_result_mcap(simulate(load_scene("paper"), duration=0.5), path)
    return path


def run_truncated(table, tmp: Path, quick: bool, domain_id: int, tools) -> None:
    from msg_tools import read_bag
    from msg_tools.cli import main as msg_tools

    sources = [_recording(tmp)] + sorted((ROOT / "bags").glob("*_golden.mcap"))
    if quick:
        sources = sources[:2]
    cut = tmp / "cut.mcap"
    for source in sources:
        raw = source.read_bytes()
        counts = {t: len(d) for t, d in read_bag(source).topics.items()}
        points = 4 if quick else 40  # (--quick: a sample; tests/test_msg_tools_damage.py cuts a recording at many more)
        for k in range(1, points + 1):
            end = len(raw) - (len(raw) * k) // (points + 1)
            cut.write_bytes(raw[:end])
            label = f"{source.name} cut at {end} of {len(raw)} bytes"
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    bag = read_bag(cut)
                lost = any(len(bag.topics.get(t, ())) < n for t, n in counts.items())
            except Exception:  # noqa: BLE001 - unreadable: every verb must refuse it
                lost = True
            status, out, err = tools._call(msg_tools, ["info", cut])
            table.add("truncated files", _judge("info", status, out, err, lost, tools), f"info {label}", err + out[-200:])
            for argv in (["compare", source, cut], ["compare", cut, source]):
                status, out, err = tools._call(msg_tools, argv)
                table.add("truncated files", _judge("compare", status, out, err, lost, tools),
                          f"compare {'golden cut' if argv[1] == source else 'cut golden'} {label}", err + out[-300:])


def _judge(verb: str, status, out: str, err: str, lost: bool, tools) -> str:
    if status is None:
        return "hang"
    if "Traceback" in err or "internal error" in err or status not in (0, 1, 2):
        return "crash"
    if status == 0:
        return "silent wrong" if lost else "ok"
    if status == 2:
        return tools._classify_cli(status, err, "msg-tools: error:", must_fail=True)
    if verb == "info":  # exit 1: a verdict that says why (a cut file is INCOMPLETE even when no message was lost)
        return "clean error" if ("INCOMPLETE" in out or "DAMAGED" in out) else "silent wrong"
    # compare FAIL: right when samples were lost, or when it names the cut file as incomplete (a file cut after
    # its data, in its summary or footer, was not finished: it fails unless --allow-incomplete); a FAIL for
    # anything else on a file that lost nothing would be wrong
    return "clean error" if lost or "is incomplete" in out else "silent wrong"


#: category runners by the name ``--only`` takes
EXTRA_CATEGORIES = {"setparameters": run_setparameters, "fifo": run_fifo_reads, "truncated": run_truncated}
