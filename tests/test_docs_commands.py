"""Every shell command in README.md, docs/**/*.md and bags/README.md runs as written.

Convention (for whoever writes docs): a fenced ```sh block is preceded, on
the line before its fence, by one marker comment:

* ``<!-- runnable -->``: its lines run one by one, each as ``sh -c LINE``,
  in a scratch copy of the repository (README.md, docs/, examples/, bags/,
  config/, launch/, and ``.venv`` linked to this one; ``belt-drive`` and
  ``msg-tools`` on the PATH), and each must exit 0.
* ``<!-- runnable: together, stop after N s -->``: long-running commands
  (nodes, sources): all lines start at once; once each has said it runs (a
  node's ``spinning with ...``, a source's ``publishing ...`` line, see
  ``RUNNING``), they run :data:`HOLD_S` more seconds together, get SIGINT and
  must each exit 0 (a line that ends by itself before must exit 0 too). A
  line that has not said so within N s (at least :data:`START_S`: a loaded
  machine starts slowly) fails. (They ran a fixed N s before; the line says
  more than the time did: a node stuck in its start-up for N s passed.)
* ``<!-- runnable: separately, stop after N s -->``: as ``together``, but
  each line in a ROS domain of its own (alternatives that must not meet).
* ``skip=TEXT`` (after ``runnable:``, comma-separated options): lines that
  contain TEXT are not run (e.g. an address of a cluster this machine has
  not got); say so in the doc's prose.
* ``<!-- not run by tests: REASON -->``: the block is not run (installs,
  the whole suite, other machines, a ROS 2 CLI this repository does not
  install); the reason says why.

A block with neither marker fails the test, so a new block decides.

A fenced ```python block takes the same two markers: ``<!-- runnable -->``
runs it verbatim as one script (``python -c``) in the scratch copy, which
must exit 0 (the README's API snippets: a renamed function or field fails).

Shortened here (the commands stay as written; what they read is made small):
the campaign files in the scratch copy of examples/ get at most 2 Monte
Carlo samples and 0.5 s runs (``_shrink_campaigns``), as tests/test_examples.py
does. Nothing else is changed.
"""

from __future__ import annotations

import os
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import yaml

from belt_drive_ros.ros import environment as ros_env

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md")), ROOT / "bags" / "README.md"]
COPIED = ("README.md", "docs", "examples", "bags", "config", "launch")
MARKER = re.compile(r"^<!--\s*(runnable(?::\s*(?P<options>.*?))?|not run by tests:\s*(?P<reason>.+?))\s*-->\s*$")
FENCE = re.compile(r"^```(?P<lang>\w*)\s*$")
SHELLS = ("sh", "bash", "shell", "console")
#: the log line by which a long-running command says it runs: a node spins its executor, a source publishes
RUNNING = re.compile(r"\]: (spinning with |publishing )")
#: seconds the long-running lines of a block run together once all say they run, before SIGINT
HOLD_S = 3.0
#: seconds a long-running line may take to say it runs, at least (the block's ``stop after N s`` when longer)
START_S = 60.0

pytestmark = pytest.mark.slow


def shell_blocks():
    """(doc, line number of the fence, marker line or '', command lines) of every shell block."""
    return [(doc, line, marker, [x for x in body if x.strip() and not x.lstrip().startswith("#")])
            for doc, line, marker, body in fenced_blocks(SHELLS)]


def fenced_blocks(languages):
    """(doc, line number of the fence, marker line or '', the block's lines) of every block in ``languages``."""
    out = []
    for doc in DOCS:
        lines = doc.read_text(encoding="utf-8").splitlines()
        k = 0
        while k < len(lines):
            m = FENCE.match(lines[k])
            if not m:
                k += 1
                continue
            end = k + 1
            while end < len(lines) and not lines[end].startswith("```"):
                end += 1
            if m.group("lang") in languages:
                marker = lines[k - 1].strip() if k > 0 and lines[k - 1].strip().startswith("<!--") else ""
                out.append((doc.relative_to(ROOT).as_posix(), k + 1, marker, lines[k + 1:end]))
            k = end + 1
    return out


BLOCKS = shell_blocks()
#: the ```python blocks: marked as the shell blocks are; a runnable one runs verbatim as one script
PYTHON_BLOCKS = fenced_blocks(("python",))


def _options(marker: str) -> dict:
    m = MARKER.match(marker)
    opts = {}
    for part in filter(None, (p.strip() for p in (m.group("options") or "").split(","))):
        if part.startswith("skip="):
            opts.setdefault("skip", []).append(part[len("skip="):])
        elif part in ("together", "separately"):
            opts["together"] = True
            opts["separately"] = part == "separately"
        elif (stop := re.fullmatch(r"stop after (\d+(?:\.\d+)?) s", part)) is not None:
            opts["stop_after"] = float(stop.group(1))
        else:
            raise AssertionError(f"unknown runnable option {part!r}")
    return opts


def test_every_shell_block_is_marked():
    unmarked = [f"{doc}:{line}" for doc, line, marker, _ in BLOCKS if not MARKER.match(marker)]
    assert not unmarked, f"shell blocks without <!-- runnable --> or <!-- not run by tests: ... -->: {unmarked}"
    runnable = [b for b in BLOCKS if MARKER.match(b[2]).group("reason") is None]
    assert len(runnable) >= 6  # the README's offline, node and campaign blocks, campaigns.md, bags/README.md


def _shrink_campaigns(folder: Path) -> None:
    for path in folder.glob("*.yaml"):
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
        if "fleet" in data:
            continue
        data.setdefault("set", {})["duration"] = 0.5
        if "monte_carlo" in data:
            data["monte_carlo"]["samples"] = min(2, data["monte_carlo"]["samples"])
        path.write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")


@pytest.fixture
def scratch(tmp_path, ros_domain_id):
    for name in COPIED:
        src = ROOT / name
        if src.is_dir():
            shutil.copytree(src, tmp_path / name, ignore=shutil.ignore_patterns("fleet", "*.campaign", "__pycache__"))
        else:
            shutil.copy2(src, tmp_path / name)
    (tmp_path / ".venv").symlink_to(Path(sys.executable).parent.parent)
    _shrink_campaigns(tmp_path / "examples")
    env = ros_env.child_environment(ros_domain_id)
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    return tmp_path, env


def _run_in_order(commands, cwd, env):
    for command in commands:
        proc = subprocess.run(["sh", "-c", command], cwd=cwd, env=env, capture_output=True, text=True, timeout=600)
        assert proc.returncode == 0, f"{command}\nexit {proc.returncode}\n{proc.stdout[-1500:]}\n{proc.stderr[-1500:]}"


def _run_together(commands, cwd, env, stop_after: float, separately: bool = False):
    envs = [env] * len(commands)
    if separately:  # a domain per line, locked for this process as the fixture's own
        envs = [{**env, "ROS_DOMAIN_ID": str(ros_env.process_domain_id(offset=40 + k))} for k in range(len(commands))]
    procs = [subprocess.Popen(["sh", "-c", f"exec {command}"], cwd=cwd, env=e, stdout=subprocess.PIPE,
                              stderr=subprocess.STDOUT, text=True, start_new_session=True)
             for command, e in zip(commands, envs)]
    outputs = [[] for _ in procs]
    running = [threading.Event() for _ in procs]

    def read(k):  # each line's output, read as it comes (a full pipe would stall the process)
        for line in procs[k].stdout:
            outputs[k].append(line)
            if RUNNING.search(line):
                running[k].set()

    readers = [threading.Thread(target=read, args=(k,), daemon=True) for k in range(len(procs))]
    for reader in readers:
        reader.start()
    try:
        deadline = time.monotonic() + max(stop_after, START_S)
        while time.monotonic() < deadline and not all(r.is_set() or p.poll() is not None for r, p in zip(running, procs)):
            time.sleep(0.1)
        time.sleep(HOLD_S)
        signalled = [proc.poll() is None for proc in procs]
        for proc, stop in zip(procs, signalled):
            if stop:
                proc.send_signal(signal.SIGINT)
        failures = []
        for command, proc, reader, out, up, stop in zip(commands, procs, readers, outputs, running, signalled):
            try:
                proc.wait(timeout=15)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
                reader.join(5)
                failures.append(f"{command}\nignored SIGINT for 15 s (killed)\n{''.join(out)[-1500:]}")
                continue
            reader.join(5)
            text = "".join(out)
            if proc.returncode != 0:
                failures.append(f"{command}\nexit {proc.returncode}\n{text[-1500:]}")
            elif stop and not up.is_set():
                failures.append(f"{command}\nstopped before it said it runs (no line matching {RUNNING.pattern!r})\n"
                                f"{text[-1500:]}")
        assert not failures, "\n\n".join(failures)
    finally:
        for proc in procs:
            if proc.poll() is None:
                proc.kill()
                proc.wait()


RUNNABLE = [b for b in BLOCKS if MARKER.match(b[2]) and MARKER.match(b[2]).group("reason") is None]


@pytest.mark.parametrize("doc,line,marker,commands", RUNNABLE, ids=[f"{b[0]}:{b[1]}" for b in RUNNABLE])
def test_documented_commands_run(scratch, doc, line, marker, commands):
    cwd, env = scratch
    opts = _options(marker)
    commands = [c for c in commands if not any(s in c for s in opts.get("skip", []))]
    assert commands, f"{doc}:{line}: nothing left to run"
    if opts.get("together"):
        _run_together(commands, cwd, env, opts.get("stop_after", 10.0), opts.get("separately", False))
    else:
        _run_in_order(commands, cwd, env)


def test_every_python_block_is_marked():
    unmarked = [f"{doc}:{line}" for doc, line, marker, _ in PYTHON_BLOCKS if not MARKER.match(marker)]
    assert not unmarked, f"python blocks without <!-- runnable --> or <!-- not run by tests: ... -->: {unmarked}"
    assert any(MARKER.match(b[2]).group("reason") is None for b in PYTHON_BLOCKS)


PYTHON_RUNNABLE = [b for b in PYTHON_BLOCKS if MARKER.match(b[2]) and MARKER.match(b[2]).group("reason") is None]


@pytest.mark.parametrize("doc,line,marker,source", PYTHON_RUNNABLE, ids=[f"{b[0]}:{b[1]}" for b in PYTHON_RUNNABLE])
def test_documented_python_runs(scratch, doc, line, marker, source):
    """A runnable python block runs verbatim (the README's API snippets), in the scratch copy, exit 0."""
    cwd, env = scratch
    proc = subprocess.run([sys.executable, "-c", "\n".join(source)], cwd=cwd, env=env, capture_output=True, text=True,
                          timeout=600)
    assert proc.returncode == 0, f"{doc}:{line}\nexit {proc.returncode}\n{proc.stdout[-1500:]}\n{proc.stderr[-1500:]}"
