"""``belt-drive bench hostile``: the hostile-input table of issue 13, re-measured (prints figures; not a test).

Every input goes through the real entry point with a time budget, and its
outcome is classified:

* **clean error**: refused in one line (``belt-drive: error:`` / ``msg-tools:
  error:``, exit 1 or 2), a damage report (``msg-tools info``: DAMAGED,
  ``compare``: FAIL), a parameter change rejected with a reason, a torque
  rejected and counted while the node keeps publishing;
* **ok**: a run or a result that is correct (an intact export, a valid run);
* **data lost**: a result that is a correct *part* of the data, said so with
  a warning (a recording truncated to its last complete chunk);
* **silent wrong**: exit 0 (or a change accepted) for an input that must be
  refused, or a result that differs from the truth without a warning;
* **crash**: a traceback, an "internal error", an exit code outside 0-2, or
  an error of more than one line (argparse's usage line followed by its one
  error line counts as a clean error); **hang**: past the budget.

Categories (the issue's): ``scene file`` (the seeded mutants of
:func:`scene_mutants`, which ``tests/test_fuzz_scenes.py`` runs too, plus
/dev/zero, a FIFO, a folder, a 2 MiB file), ``cli`` (huge and invalid
durations and steps, bad outputs: /dev/full, folders, unknown extensions,
existing files; a streaming run stopped by SIGTERM or SIGINT while it writes, in a
child process), ``mcap info`` / ``mcap export`` / ``mcap compare`` (:func:`mcap_mutants` of a
recording through each verb, compare against the intact file, as
``tests/test_msg_tools_damage.py``; ``info`` checks the data against the
summary section as ``export`` and ``compare`` do, so all three refuse or
report the same files),
``campaign file`` (the campaign mutants, special files and ``sweep`` options of
:mod:`~belt_drive_ros.benchmarks.hostile_campaign`, through ``belt-drive sweep
--check``), ``bag folder`` (a split rosbag2 folder with its ``metadata.yaml``
or files damaged, through ``msg-tools info``, ``export`` and ``compare``),
``campaign run`` (whole sweeps in child processes: failing variants, SIGINT,
SIGTERM, SIGKILL and a resume, a fleet changed before its resume),
``node torque`` (absurd and non-finite drive torques), ``node parameter``
(hostile scene files over ``scene``, absurd values) and ``node reset flood``.
The table goes to stdout, ``hostile.csv`` and ``hostile.md`` in ``--out``;
the inputs that were not a clean error or ok to ``hostile_details.txt``.
Exit status 1 if any input crashed, hung or was silently wrong.

Usage::

    belt-drive bench hostile --out /tmp/hostile          # ~1,300 inputs, minutes
    belt-drive bench hostile --quick --out /tmp/hostile  # a sample (for the test)
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import io
import math
import os
import random
import shutil
import signal
import struct
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml
from mcap.reader import make_reader

from msg_tools import Ros2McapWriter

from ..core.params import OPTIONAL_DEFAULTS
from ..core.scene import REQUIRED_KEYS
from .hostile_campaign import run_campaign_runs
from .hostile_paths import EXTRA_CATEGORIES  # issue 24: node SetParameters, FIFO read paths, truncated files

OUTCOMES = ("clean error", "ok", "data lost", "silent wrong", "crash", "hang")
#: the categories of ``--only`` (campaign files and bag folders: :mod:`belt_drive_ros.benchmarks.hostile_campaign`)
CATEGORIES = ("scene", "cli", "mcap", "campaign", "bagdir", "sweep", "node", *EXTRA_CATEGORIES)
#: seconds one input may take
BUDGET_S = 20.0


def _profile_ranges(kind: str) -> dict:
    from ..core.sources import _REGISTRY

    cls = _REGISTRY.get(kind)
    return dict(getattr(cls, "PLAUSIBLE", {})) if cls is not None else {}


# ------------------------------------------------------------------ generators (shared with the tests)
def _load_scene(name):
    from ..io.scenes import load_scene

    return load_scene(name)


#: joint names of :func:`write_recording`'s JointState messages
JOINTS = ["wheel_M", "wheel_3"]
SCENES = ("paper", "truck_compressor", "e_motor_start", "bsg_start")

#: PyYAML's safe dumper in C (libyaml) where it is built, else in Python: the same text (tests/test_fuzz_scenes.py
#: compares them), ~10x faster on the mutants' long strings (all 781 scene mutants: 10.9 -> 1.0 s)
SAFE_DUMPER = getattr(yaml, "CSafeDumper", yaml.SafeDumper)


def _dump(data) -> str:
    return yaml.dump(data, Dumper=SAFE_DUMPER, sort_keys=False)


class _Quoting(SAFE_DUMPER):
    """Writes every string quoted: a mutant's text value stays text for any YAML version (1e3 is a number in 1.2)."""


_Quoting.add_representer(str, lambda dumper, value: dumper.represent_scalar("tag:yaml.org,2002:str", value, style="'"))


def _quoted(data) -> bytes:
    return yaml.dump(data, Dumper=_Quoting, sort_keys=False).encode()


def scene_mutants(seed: int = 13):
    """(category, must_fail, label, file bytes) of every scene-file mutant (seeded: the same every run).

    Mutants of the shipped scenes: missing keys, wrong types, aliases, nesting, duplicates, huge
    numbers (parameters, time settings and profile fields), binary and cut-off files. ``must_fail``:
    exit 0 would be a silent wrong answer.
    """
    rng = random.Random(seed)
    for name in SCENES:
        base = _load_scene(name).to_dict()
        text = _dump(base)
        # missing keys: every required top-level key, every required parameter
        for key in REQUIRED_KEYS:
            yield "missing key", True, f"{name} -{key}", _dump({k: v for k, v in base.items() if k != key}).encode()
        for key in base["params"]:
            if key not in OPTIONAL_DEFAULTS:
                params = {k: v for k, v in base["params"].items() if k != key}
                yield "missing key", True, f"{name} -params.{key}", _dump({**base, "params": params}).encode()
        # wrong types: text, lists, mappings, null, booleans where numbers or mappings belong
        for key in ("duration", "dt", "output_rate", "params", "drive", "load", "initial_state", "method_options"):
            for bad in ("12", "1e3", [1.0, 2.0], {"x": 1}, None, True, "x" * 100_000):
                # null for an optional key means "not given" (its documented default): a run, not an error
                must_fail = not (bad is None and key in ("initial_state", "method_options"))
                yield "wrong type", must_fail, f"{name} {key}={str(bad)[:12]!r}", _quoted({**base, key: bad})
        for key in rng.sample(sorted(base["params"]), 6):
            for bad in ("2e4", "12", [1.0], {"v": 1.0}, None, True):
                yield "wrong type", True, f"{name} params.{key}={bad!r}", _quoted({**base, "params": {**base["params"], key: bad}})
        for profile in ("drive", "load"):
            for key in [k for k in base[profile] if k != "type"][:3]:
                yield "wrong type", True, f"{name} {profile}.{key}='7'", _quoted({**base, profile: {**base[profile], key: "7"}})
        # aliases and anchors
        yield "alias", True, f"{name} alias", (text + "extra: &a 1.0\n").replace("duration:", "duration: &d", 1).encode()
        bomb = "a: &a [x,x,x,x,x,x,x,x,x]\n" + "".join(
            f"{chr(98 + i)}: &{chr(98 + i)} [" + ",".join([f"*{chr(97 + i)}"] * 9) + "]\n" for i in range(8))
        yield "alias", True, f"{name} billion laughs", (bomb + text).encode()
        yield "alias", True, f"{name} merge key", text.replace("params:\n", "params:\n  <<: {k: 1.0}\n", 1).encode()
        # deep nesting
        for depth in (40, 1000, 100_000):
            yield "nesting", True, f"{name} nest {depth}", (text + "description: " + "[" * depth + "]" * depth + "\n").encode()
        # duplicates: a top-level line repeated, a parameter repeated
        lines = text.splitlines(keepends=True)
        top = [ln for ln in lines if ln[:1].isalpha()]
        for line in rng.sample(top, 3):
            yield "duplicate", True, f"{name} dup {line.split(':')[0]}", (text + line).encode()
        k_line = next(ln for ln in lines if ln.startswith("  k:"))
        yield "duplicate", True, f"{name} dup params.k", text.replace(k_line, k_line + "  k: 1.0e5\n", 1).encode()
        # huge and tiny numbers in parameters and time settings
        for key, value in (("dt", 1e-300), ("dt", 1e300), ("duration", 1e9), ("duration", 1e300), ("output_rate", 1e12),
                           ("output_rate", 1e-300), ("duration", -1.0), ("dt", float("nan")), ("duration", float("inf"))):
            yield "huge number", True, f"{name} {key}={value}", _dump({**base, key: value}).encode()
        for key in rng.sample(sorted(base["params"]), 5):
            for value in (1e300, -1e300, float("inf"), 10**400):
                yield "huge number", True, f"{name} params.{key}={value}", _dump({**base, "params": {**base["params"], key: value}}).encode()
        for profile in ("drive", "load"):  # profile fields with a plausible range (core.sources)
            numeric = [k for k, v in base[profile].items() if k != "type" and isinstance(v, (int, float))
                       and not isinstance(v, bool) and k in _profile_ranges(base[profile]["type"])]
            for key in numeric[:3]:
                yield "huge number", True, f"{name} {profile}.{key}=1e12", _dump({**base, profile: {**base[profile], key: 1e12}}).encode()
        # binary: random bytes, flipped bytes, cut-off files, NUL, non-UTF-8
        raw = text.encode()
        for i in range(4):
            yield "binary", True, f"{name} random {i}", bytes(rng.randrange(256) for _ in range(rng.randrange(1, 4000)))
        yield "binary", True, f"{name} latin-1", text.replace("description:", "description: caf\xe9 ", 1).encode("latin-1")
        for i in range(12):
            b = bytearray(raw)
            for _ in range(rng.randrange(1, 4)):
                b[rng.randrange(len(b))] = rng.randrange(256)
            yield "binary", False, f"{name} flip {i}", bytes(b)
        for cut in sorted(rng.sample(range(1, len(raw)), 10)):
            yield "binary", False, f"{name} cut {cut}", raw[:cut]
        yield "binary", True, f"{name} empty", b""
        yield "binary", True, f"{name} NUL", b"\x00" * 64


def write_recording(path, n=600, skip=(), duplicate=()):
    """A 1 kHz recording (torque + joint states) in small chunks (~12 of them); ``skip`` and
    ``duplicate``: sample indexes left out or written twice."""
    with Ros2McapWriter(path, force=True, chunk_size=4096, flush_interval_s=None) as w:
        w.add_metadata("units", {"/drive_torque": "N*m"})
        for i in range(n):
            if i in skip:
                continue
            for _ in range(2 if i in duplicate else 1):
                t = 10**9 + i * 1_000_000
                w.write("/drive_torque", "std_msgs/msg/Float64", {"data": float(np.sin(i / 30))}, t)
                w.write("/joint_states", "sensor_msgs/msg/JointState", {
                    "header": {"stamp": {"sec": t // 10**9, "nanosec": t % 10**9}}, "name": JOINTS,
                    "position": [i * 1e-3, i * 2e-3], "velocity": [1.0 + i, 2.0], "effort": [0.5, -0.5]}, t)
    return Path(path)


def chunk_indexes(raw):
    """The chunk indexes of the MCAP bytes ``raw`` in file order."""
    return sorted(make_reader(io.BytesIO(raw)).get_summary().chunk_indexes, key=lambda c: c.chunk_start_offset)


def drop_chunk(raw, k):
    """``raw`` without its chunk ``k`` (and that chunk's message index)."""
    c = chunk_indexes(raw)[k]
    return raw[: c.chunk_start_offset] + raw[c.chunk_start_offset + c.chunk_length + c.message_index_length:]


def duplicate_chunk(raw, k):
    """``raw`` with its chunk ``k`` (and message index) written twice in a row."""
    c = chunk_indexes(raw)[k]
    end = c.chunk_start_offset + c.chunk_length + c.message_index_length
    return raw[:end] + raw[c.chunk_start_offset:end] + raw[end:]


def mcap_mutants(raw):
    """(label, bytes) of ~270 mutants of the MCAP file ``raw``: truncated, bits flipped, chunks dropped
    or duplicated, huge chunk sizes and record lengths (seeded)."""
    rng = np.random.default_rng(12)
    size = len(raw)
    for cut in sorted(set(np.linspace(1, size - 1, 40).astype(int).tolist())):
        yield f"truncated at {cut}", raw[:cut]
    for at in sorted(rng.choice(size, 80, replace=False).tolist()):
        flipped = bytearray(raw)
        flipped[at] ^= 1 << int(rng.integers(8))
        yield f"bit flipped at {at}", bytes(flipped)
    for k in range(len(chunk_indexes(raw))):
        yield f"chunk {k} dropped", drop_chunk(raw, k)
        yield f"chunk {k} duplicated", duplicate_chunk(raw, k)
    # huge sizes inside each chunk's header: uncompressed size (a decompression bomb claim) and
    # the compressed records' length (Chunk: start u64, end u64, uncompressed_size u64, crc u32,
    # compression string u32+bytes, records length u64)
    for k, c in enumerate(chunk_indexes(raw)):
        body = c.chunk_start_offset + 9
        compression_len = struct.unpack_from("<I", raw, body + 28)[0]
        for field, offset in (("uncompressed size", body + 16), ("records length", body + 32 + compression_len)):
            for length in (2**62, 2**40, size * 1000):
                mutant = bytearray(raw)
                struct.pack_into("<Q", mutant, offset, length)
                yield f"chunk {k} {field} claims {length} bytes", bytes(mutant)
    # huge lengths in the headers of top-level records
    pos = 8
    starts = []
    while pos + 9 <= size - 8:
        starts.append(pos)
        pos += 9 + struct.unpack_from("<Q", raw, pos + 1)[0]
    for at in starts[:: max(1, len(starts) // 15)]:
        for length in (2**63 - 1, 2**40, size):
            mutant = bytearray(raw)
            struct.pack_into("<Q", mutant, at + 1, length)
            yield f"record at {at} claims {length} bytes", bytes(mutant)


# ------------------------------------------------------------------ running one input
class _Hang(BaseException):
    """Raised by the timer: an input ran past its budget."""


@contextlib.contextmanager
def _budget(seconds: float):
    def alarm(signum, frame):
        raise _Hang()

    old = signal.signal(signal.SIGALRM, alarm)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


def _call(main, argv, budget: float = BUDGET_S):
    """(exit status or None for a hang, stdout, stderr) of ``main(argv)`` in this process."""
    out, err = io.StringIO(), io.StringIO()
    try:
        with _budget(budget), contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            status = main([str(a) for a in argv])
    except _Hang:
        status = None
    except SystemExit as exc:  # argparse
        status = exc.code if isinstance(exc.code, int) else 2
    except BaseException as exc:  # noqa: BLE001 - an exception out of main is a crash
        err.write(f"Traceback (escaped main): {type(exc).__name__}: {exc}\n")
        status = -1
    return status, out.getvalue(), err.getvalue()


def _classify_cli(status, err: str, prefix: str, must_fail: bool) -> str:
    if status is None:
        return "hang"
    lines = err.strip().splitlines()
    if "Traceback" in err or "internal error" in err or status not in (0, 1, 2):
        return "crash"
    if status == 0:
        return "silent wrong" if must_fail else "ok"
    errors = [ln for ln in lines if ln.startswith(prefix)]
    if len(errors) == 1 and len(errors[0]) < 500:
        return "clean error"
    # argparse's own refusal of an option value: its usage line, then one error line, exit 2
    usage = status == 2 and len(lines) >= 2 and lines[0].startswith("usage:") and ": error: " in lines[-1]
    return "clean error" if usage else "crash"


class Table:
    """Counts per category and outcome, and the details of the bad ones."""

    def __init__(self):
        self.counts = collections.OrderedDict()
        self.details: list[str] = []

    def add(self, category: str, outcome: str, label: str, note: str = "") -> None:
        row = self.counts.setdefault(category, collections.Counter())
        row[outcome] += 1
        row["tried"] += 1
        if outcome not in ("clean error", "ok"):
            self.details.append(f"{category}: {outcome}: {label}: {' '.join(note.split())[:300]}")

    def bad(self) -> int:
        return sum(row[o] for row in self.counts.values() for o in ("crash", "hang", "silent wrong"))

    def rows(self):
        for category, row in self.counts.items():
            yield [category, row["tried"], *[row[o] for o in OUTCOMES]]

    def text(self) -> str:
        header = ["category", "inputs tried", *OUTCOMES]
        rows = [header] + [[str(v) for v in r] for r in self.rows()]
        total = ["total", *[str(sum(r[k] for r in self.rows())) for k in range(1, len(header))]]
        rows.append(total)
        widths = [max(len(r[k]) for r in rows) for k in range(len(header))]
        return "\n".join("  ".join(c.rjust(w) if k else c.ljust(w) for k, (c, w) in enumerate(zip(r, widths)))
                         for r in rows)

    def markdown(self) -> str:
        header = ["category", "inputs tried", *OUTCOMES]
        lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
        lines += ["| " + " | ".join(str(v) for v in r) + " |" for r in self.rows()]
        return "\n".join(lines) + "\n"


# ------------------------------------------------------------------ categories
def run_scene_files(table: Table, tmp: Path, quick: bool) -> None:
    """The seeded scene mutants and special files through ``belt-drive sim FILE --duration 0.02``."""
    from ..cli import main

    mutants = list(scene_mutants())
    if quick:
        mutants = mutants[::25]
    path = tmp / "mutant.yaml"
    for category, must_fail, label, data in mutants:
        path.write_bytes(data)
        status, _, err = _call(main, ["sim", path, "--quiet", "--duration", "0.02"])
        table.add("scene file", _classify_cli(status, err, "belt-drive: error: ", must_fail), f"{category} [{label}]", err)
    fifo = tmp / "scene.fifo"
    os.mkfifo(fifo)
    folder = tmp / "folder.yaml"
    folder.mkdir()
    big = tmp / "big.yaml"
    big.write_bytes(b"# " + b"x" * (2 * 2**20))
    for special in ("/dev/zero", str(fifo), str(folder), str(big)):
        status, _, err = _call(main, ["sim", special, "--quiet", "--duration", "0.02"])
        table.add("scene file", _classify_cli(status, err, "belt-drive: error: ", True), f"special {special}", err)


def run_cli(table: Table, tmp: Path, quick: bool) -> None:
    """Command-line values and outputs through ``belt-drive sim``."""
    from ..cli import main

    keep_png, keep_csv = tmp / "keep.png", tmp / "keep.csv"
    keep_png.write_bytes(b"keep"), keep_csv.write_bytes(b"keep")
    (tmp / "outdir.csv").mkdir()
    short = ["--duration", "0.05", "--quiet"]
    cases = [  # (argv, must fail)
        (["sim", "paper", "--duration", "1e9", "--quiet"], True),
        (["sim", "paper", "--duration", "1e300", "--quiet"], True),
        (["sim", "paper", "--duration", "-1", "--quiet"], True),
        (["sim", "paper", "--duration", "nan", "--quiet"], True),
        (["sim", "paper", "--duration", "inf", "--quiet"], True),
        (["sim", "paper", "--dt", "1e-300", *short], True),
        (["sim", "paper", "--dt", "0", *short], True),
        (["sim", "paper", "--dt", "1e300", *short], True),
        (["sim", "paper", *short, "--out", "/dev/full"], True),
        (["sim", "paper", *short, "--out", "/dev/null"], True),
        (["sim", "paper", *short, "--out", tmp / "x.xyz"], True),
        (["sim", "paper", *short, "--out", tmp / "outdir.csv"], True),
        (["sim", "paper", *short, "--out", tmp / "no" / "such" / "x.csv"], True),
        (["sim", "paper", *short, "--out", keep_csv], True),
        (["sim", "paper", *short, "--plot", tmp / "x.csv"], True),
        (["sim", "paper", *short, "--plot", "/dev/full"], True),
        (["sim", "paper", *short, "--plot", keep_png], True),
        (["sim", "paper", *short, "--out", tmp / "x.MCAP"], False),
        (["sim", "paper", *short, "--out", tmp / "x.CSV"], False),
        (["sim", "no_such_scene", *short], True),
        (["sim", "paper", *short, "--method", "nope"], True),
        (["sim", "paper", *short, "--model", "nope"], True),
    ]
    cases += [  # round 2: other commands, refused before anything runs (labelled with their command)
        (["sim", "paper", *short, "--out", "/proc/x.csv"], True),
        (["sim", "paper", *short, "--method-option", "=1"], True),
        (["sim", "", "--quiet"], True),
        (["sim", "fead_i4", *short, "--method", "auto"], True),
        (["scenes", ""], True),
        (["source", "engine", "--harmonics", ",,,", "--print"], True),
        (["source", "engine", "--max-torque", "-5", "--print"], True),
        (["source", "engine", "--initial-speed", "nan", "--print"], True),
        (["node", "paper", "--name", "a b"], True),
        (["record", "--out", tmp / "x.txt", "--duration", "1"], True),
        (["bench", "hostile", "--only", "nope", "--out", tmp / "bench"], True),
    ]
    for argv, must_fail in cases:
        status, _, err = _call(main, argv)
        outcome = _classify_cli(status, err, "belt-drive: error: ", must_fail)
        if outcome == "clean error" and (keep_png.read_bytes() != b"keep" or keep_csv.read_bytes() != b"keep"):
            outcome = "data lost"  # refused, but an existing file was overwritten
        if outcome == "ok" and argv[-2] == "--out" and not Path(argv[-1]).is_file():
            outcome = "silent wrong"  # exit 0 without the output
        leftovers = [p.name for p in tmp.iterdir() if p.name.endswith(".part")]
        if leftovers:
            outcome = "data lost"
        table.add("cli", outcome, " ".join(str(a) for a in (argv[1:] if argv[0] == "sim" and argv[1] == "paper" else argv)), err)
    if not quick:
        for sig in (signal.SIGTERM, signal.SIGINT):
            label, outcome, note = _signalled_run(tmp, sig)
            table.add("cli", outcome, label, note)


def _signalled_run(tmp: Path, sig) -> tuple:
    """``belt-drive sim paper --duration 5000 --out F.csv --force`` (a child process, streaming) sent
    ``sig`` once its temporary file holds data: (label, outcome, note). Clean: exit 128 + signal,
    one line, the old F.csv kept and no temporary file left; data lost: a temporary file left
    behind or the old file gone; hang: the child neither finished nor stopped."""
    import subprocess

    out = tmp / f"signalled_{sig.name}.csv"
    out.write_bytes(b"keep")
    label = f"sim paper --duration 100000 --out {out.name} --force, {sig.name} while writing"
    cmd = [sys.executable, "-m", "belt_drive_ros.cli", "sim", "paper", "--duration", "100000", "--quiet", "--force",
           "--out", str(out)]
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[2])}
    child = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=env, cwd=tmp,
                             preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        deadline = time.monotonic() + 300.0
        while not any(p.stat().st_size > 0 for p in tmp.glob(f".{out.name}.*.part")):
            if child.poll() is not None or time.monotonic() > deadline:
                return label, "hang" if child.poll() is None else "crash", "no temporary output while running"
            time.sleep(0.05)
        child.send_signal(sig)
        err = child.communicate(timeout=BUDGET_S)[1]
    except subprocess.TimeoutExpired:
        return label, "hang", f"no exit {BUDGET_S:g} s after {sig.name}"
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()
    left = [p.name for p in tmp.glob(f".{out.name}.*.part")]
    if left or out.read_bytes() != b"keep":
        return label, "data lost", f"exit {child.returncode}, left {left}, old file kept: {out.read_bytes() == b'keep'}"
    lines = err.strip().splitlines()
    if child.returncode == 128 + sig and len(lines) == 1 and lines[0].startswith("belt-drive: interrupted"):
        return label, "clean error", err
    return label, "crash", f"exit {child.returncode}: {err}"


def run_mcap(table: Table, tmp: Path, quick: bool) -> None:
    """MCAP mutants through ``msg-tools info``, ``export`` and ``compare`` against the intact file."""
    from msg_tools.cli import main

    good = write_recording(tmp / "good.mcap")
    raw = good.read_bytes()
    golden = _call(main, ["export", good, "--topic", "/joint_states"])[1].splitlines()
    mutants = list(mcap_mutants(raw))
    if quick:
        mutants = mutants[::20]
    path = tmp / "mutant.mcap"
    for label, data in mutants:
        path.write_bytes(data)
        three_verbs(table, ("mcap export", "mcap info", "mcap compare"), path, good, golden, label)


def three_verbs(table: Table, categories, path, good, golden: list, label: str) -> None:
    """``msg-tools export`` (the joint states, against ``golden``: the intact file's export), ``info`` and
    ``compare`` against ``good`` of the damaged ``path``, classified into ``categories`` (export, info, compare)."""
    from msg_tools.cli import main

    status, out, err = _call(main, ["export", path, "--topic", "/joint_states"])
    rows = out.splitlines() if status == 0 else None
    warned = "warning:" in err
    intact = rows == golden
    prefix = rows is not None and warned and rows[:1] == golden[:1] and rows == golden[: len(rows)]
    table.add(categories[0], _classify_mcap("export", status, out, err, intact, prefix), f"export {label}", err)
    status, out, err = _call(main, ["info", path])
    table.add(categories[1], _classify_mcap("info", status, out, err, intact, prefix or (warned and rows is None)),
              f"info {label}", err + out[-200:])
    status, out, err = _call(main, ["compare", path, good])
    table.add(categories[2], _classify_mcap("compare", status, out, err, intact, prefix), f"compare {label}", err)


def _classify_mcap(verb, status, out, err, intact: bool, prefix: bool) -> str:
    if status is None:
        return "hang"
    if "Traceback" in err or "internal error" in err or status not in (0, 1, 2):
        return "crash"
    if status == 2:
        lines = [ln for ln in err.splitlines() if ln.startswith("msg-tools: error:")]
        return "clean error" if len(lines) == 1 else "crash"
    if status == 1:  # info: DAMAGED or INCOMPLETE; compare: FAIL
        return "clean error" if ("DAMAGED" in out or "INCOMPLETE" in out or verb == "compare") else "crash"
    if intact:
        return "ok"
    return "data lost" if prefix and "warning:" in err else "silent wrong"


def run_node(table: Table, tmp: Path, quick: bool, domain_id: int) -> None:
    """The node in-process (harness): absurd torques, hostile parameter values, a reset flood."""
    from ..ros.harness import BeltDriveHarness

    fifo = tmp / "node_scene.fifo"
    os.mkfifo(fifo)
    bomb = tmp / "bomb.yaml"
    bomb.write_text("a: &a [1, 1, 1, 1, 1, 1, 1, 1, 1]\n" + "".join(
        f"{chr(98 + k)}: &{chr(98 + k)} [" + ", ".join([f"*{chr(97 + k)}"] * 9) + "]\n" for k in range(8)))
    binary = tmp / "binary.yaml"
    binary.write_bytes(bytes(range(256)) * 8)
    big = tmp / "big_scene.yaml"
    big.write_bytes(b"# " + b"x" * (2 * 2**20))
    torques = [1e6, -1e6, 1e12, 1e300, -1e300, float("nan"), float("inf"), float("-inf")]
    params = [  # (name, value): every one must be rejected
        ("scene", "/dev/zero"), ("scene", str(fifo)), ("scene", str(tmp)), ("scene", str(bomb)),
        ("scene", str(binary)), ("scene", str(big)), ("scene", "no_such_scene"),
        ("k", -1.0), ("k", 1e300), ("k", float("nan")), ("c", -1.0), ("I_M", 0.0), ("I_M", 1e300),
        ("step_rate_hz", 1e12), ("step_rate_hz", 0.0), ("substeps", 10**9), ("substeps", 0),
        ("torque_bound", -1.0), ("torque_limit", float("nan")), ("model", "nope"), ("method", "nope"),
        ("real_time_factor", -1.0), ("input_timeout", float("nan")), ("record_path", str(tmp / "x.mcap")),
        ("max_bag_size", -1), ("drive_source", "nope"), ("timeout_behavior", "nope"),
    ]
    if quick:
        torques, params = torques[::2], params[::3]
    with _budget(600.0), BeltDriveHarness(domain_id=domain_id, input_timeout=0.0) as h:
        h.publish_torque(2.0)
        h.advance(0.01)
        for value in torques:
            label = f"drive_torque {value:g}"
            try:
                with _budget(BUDGET_S):
                    before = h.outputs()["time"].size
                    rejected = h.node.counters.get("rejected", None)
                    h.publish_torque(value)
                    h.advance(0.01)
                    out = h.outputs()
                    applied = out["drive_torque"][-1]
                    ticking = out["time"].size == before + 10 and all(np.all(np.isfinite(v[-10:])) for v in out.values())
                    if ticking and applied == 2.0:
                        outcome = "clean error"  # rejected, counted, still publishing
                    elif ticking:
                        outcome = "silent wrong" if not math.isfinite(value) or abs(value) > h.node.settings.torque_bound else "ok"
                    else:
                        outcome = "silent wrong"  # outputs stopped or went non-finite
                    del rejected
            except _Hang:
                outcome = "hang"
            except Exception as exc:  # noqa: BLE001
                outcome, label = "crash", f"{label}: {type(exc).__name__}: {exc}"
            table.add("node torque", outcome, label)
            h.publish_torque(2.0)
            h.advance(0.002)
        for name, value in params:
            label = f"{name}={value!r}"
            try:
                with _budget(BUDGET_S):
                    old = h.node.get_parameter(name).value
                    result = h.set_parameters(**{name: value})
                    before = h.outputs()["time"].size
                    h.advance(0.005)
                    ticking = h.outputs()["time"].size == before + 5
                    if result.successful:
                        outcome = "silent wrong"
                    elif not ticking or h.node.get_parameter(name).value != old:
                        outcome = "silent wrong"
                    elif result.reason and len(result.reason) < 500:
                        outcome = "clean error"
                    else:
                        outcome = "crash"
                    label += f": {result.reason[:120]}"
            except _Hang:
                outcome = "hang"
            except Exception as exc:  # noqa: BLE001
                outcome, label = "crash", f"{label}: {type(exc).__name__}: {exc}"
            table.add("node parameter", outcome, label)
        # an integer for a double parameter: taken as the double it denotes, the type stays DOUBLE
        try:
            with _budget(BUDGET_S):
                result = h.set_parameters(k=5)
                kept = h.node.get_parameter("k")
                from rclpy.parameter import Parameter

                right = result.successful and kept.type_ == Parameter.Type.DOUBLE and kept.value == 5.0
                outcome = "ok" if right else ("clean error" if not result.successful else "silent wrong")
        except _Hang:
            outcome = "hang"
        except Exception as exc:  # noqa: BLE001
            outcome = "crash"
        table.add("node parameter", outcome, "k=5 (an integer for a double)")
        from std_srvs.srv import Trigger

        calls = 100 if quick else 1000
        try:
            with _budget(120.0):
                futures = [h._reset_client.call_async(Trigger.Request()) for _ in range(calls)]
                h._spin_until(lambda: all(f.done() for f in futures), f"{calls} ~/reset answers", timeout=100.0)
                before = h.outputs()["time"].size
                h.advance(0.005)
                answered = sum(1 for f in futures if f.done() and f.result().success)
                ok = answered == calls and h.outputs()["time"].size == before + 5
                outcome = "ok" if ok else "data lost"
        except _Hang:
            outcome = "hang"
        except Exception as exc:  # noqa: BLE001
            outcome = "crash" if not isinstance(exc, TimeoutError) else "data lost"
        table.add("node reset flood", outcome, f"{calls} asynchronous ~/reset calls")


# ------------------------------------------------------------------ campaign files and bag folders
def classify_check(status, out: str, err: str, must_fail: bool, variants: int | None) -> str:
    """Outcome of ``belt-drive sweep FILE --check``: clean error, ok, crash, hang or silent wrong."""
    outcome = _classify_cli(status, err, "belt-drive: error: ", must_fail)
    if outcome in ("ok", "clean error") and variants is not None and status in (0, 1):
        # the variant count --check reports must be the one the file states
        if f"{variants:,} variant{'s' if variants != 1 else ''} (" not in out:
            return "silent wrong"
    return outcome


def run_campaign_files(table, tmp: Path, quick: bool) -> None:
    """The campaign mutants, special files and command-line values through ``belt-drive sweep FILE --check``."""
    from ..cli import main
    from .hostile_campaign import GRID_MC, campaign_mutants, dump_campaign, make_fleet, special_campaign_files

    mutants = list(campaign_mutants())
    if quick:  # (a sample: tests/test_fuzz_campaigns.py runs them all)
        mutants = mutants[::25]
    for k, (category, must_fail, label, data, variants, setup) in enumerate(mutants):
        folder = tmp / f"m{k}"
        folder.mkdir()
        make_fleet(folder, setup)
        path = folder / "campaign.yaml"
        path.write_bytes(data)
        status, out, err = _call(main, ["sweep", path, "--check", "--quiet"])
        table.add("campaign file", classify_check(status, out, err, must_fail, variants), f"{category} [{label}]", err)
        shutil.rmtree(folder, ignore_errors=True)
    good = tmp / "good.yaml"
    good.write_bytes(dump_campaign(GRID_MC))
    for label, path in special_campaign_files(tmp):
        status, out, err = _call(main, ["sweep", path, "--check", "--quiet"])
        table.add("campaign file", classify_check(status, out, err, True, None), f"special [{label}]", err)
    for argv in (["--workers", "1000000"], ["--workers", "0"], ["--workers", "-3"], ["--batch-size", "0"],
                 ["--scheduler", "nonsense://x"], ["--scheduler", "tcp://127.0.0.1:1", "--workers", "2"],
                 ["--workers", "x"]):  # fmt: skip
        # without --check: refused before a cluster starts (a scheduler address is tried, the rest checked up front)
        status, out, err = _call(main, ["sweep", good, "--quiet", "--out", tmp / "cli.campaign", *argv])
        table.add("campaign file", classify_check(status, out, err, True, None), f"cli [{' '.join(argv)}]", err)
    status, out, err = _call(main, ["sweep", tmp / "no_such.yaml", "--check"])
    table.add("campaign file", classify_check(status, out, err, True, None), "cli [missing file]", err)


def write_bag_folder(folder: Path) -> Path:
    """A rosbag2 folder of three split files (1 kHz torque and joint states, 0.6 s), written by Ros2BagWriter."""
    from msg_tools.bagdir import Ros2BagWriter

    with Ros2BagWriter(folder, force=True, max_bag_duration=0.2, chunk_size=4096) as w:
        for i in range(600):
            t = 10**9 + i * 1_000_000
            w.write("/drive_torque", "std_msgs/msg/Float64", {"data": float(np.sin(i / 30))}, t)
            w.write("/joint_states", "sensor_msgs/msg/JointState", {
                "header": {"stamp": {"sec": t // 10**9, "nanosec": t % 10**9}}, "name": JOINTS,
                "position": [i * 1e-3, i * 2e-3], "velocity": [1.0 + i, 2.0], "effort": [0.5, -0.5]}, t)
    return folder


def run_bag_folders(table, tmp: Path, quick: bool) -> None:
    """Bag-folder mutants through ``msg-tools info``, ``export`` and ``compare`` against the intact folder."""
    from msg_tools.cli import main

    from .hostile_campaign import bag_folder_mutants

    good = write_bag_folder(tmp / "good")
    golden = _call(main, ["export", good, "--topic", "/joint_states"])[1].splitlines()
    mutants = list(bag_folder_mutants(good))
    if quick:  # (a sample: tests/test_fuzz_campaigns.py runs them all)
        mutants = mutants[::15]
    for k, (label, change) in enumerate(mutants):
        path = tmp / f"bag{k}"
        shutil.copytree(good, path)
        change(path)
        three_verbs(table, ("bag folder",) * 3, path, good, golden, label)
        shutil.rmtree(path, ignore_errors=True)


# ------------------------------------------------------------------ main
def parse_args(argv=None):
    p = argparse.ArgumentParser(prog="belt-drive bench hostile", description=__doc__.split("\n\n")[0])
    p.add_argument("--out", type=Path, default=Path("docs/bench"), help="folder for hostile.csv/.md (default docs/bench)")
    p.add_argument("--quick", action="store_true", help="a sample of each category (seconds to a minute)")
    p.add_argument("--only", nargs="+", choices=CATEGORIES, help="run only these categories")
    p.add_argument("--domain-id", type=int, help="ROS domain of the node category (default: private to this process)")
    return p.parse_args(argv)


def main(argv=None) -> int:
    args = parse_args(argv)
    from ..ros import environment as ros_env

    ros_env.configure_environment(loopback=True)
    table = Table()
    todo = args.only or CATEGORIES
    start = time.monotonic()
    timings = {}
    with tempfile.TemporaryDirectory(prefix="belt_drive_hostile_") as tmp:
        for name in todo:
            folder = Path(tmp) / name
            folder.mkdir()
            t0 = time.monotonic()
            offline = {"scene": run_scene_files, "cli": run_cli, "mcap": run_mcap, "campaign": run_campaign_files,
                       "bagdir": run_bag_folders, "sweep": run_campaign_runs}
            domain = args.domain_id if args.domain_id is not None else ros_env.process_domain_id(offset=37)
            if name in offline:
                offline[name](table, folder, args.quick)
            elif name in EXTRA_CATEGORIES:
                EXTRA_CATEGORIES[name](table, folder, args.quick, domain, sys.modules[__name__])
            else:
                run_node(table, folder, args.quick, domain)
            timings[name] = time.monotonic() - t0
    text = table.text()
    load = os.getloadavg()[0]
    head = (f"belt-drive hostile inputs{' (quick sample)' if args.quick else ''}: "
            f"{sum(r[1] for r in table.rows())} inputs in {time.monotonic() - start:.0f} s "
            f"(budget {BUDGET_S:g} s each), load average {load:.2f}, {os.cpu_count()} CPUs")
    print(head)
    print(text)
    from ..io.atomic import atomic_output

    args.out.mkdir(parents=True, exist_ok=True)
    with atomic_output(args.out / "hostile.csv", force=True, mode="w") as f:
        f.write(",".join(["category", "inputs tried", *OUTCOMES]) + "\n")
        for row in table.rows():
            f.write(",".join(str(v) for v in row) + "\n")
    with atomic_output(args.out / "hostile.md", force=True, mode="w") as f:
        f.write(f"{head}\n\n{table.markdown()}")
    with atomic_output(args.out / "hostile_details.txt", force=True, mode="w") as f:
        f.write("\n".join(table.details) + ("\n" if table.details else ""))
    print(f"wrote {args.out / 'hostile.csv'}, {args.out / 'hostile.md'}, {args.out / 'hostile_details.txt'} "
          f"({len(table.details)} inputs not a clean error or ok)")
    return 1 if table.bad() else 0


if __name__ == "__main__":
    raise SystemExit(main())
