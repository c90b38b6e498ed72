"""Fuzzed scene files (issue 13): every mutant gives a clean one-line error or a run; none crashes, hangs or is taken silently.

Mutants of the shipped scenes, seeded (the same every run), in the
categories of the issue: missing keys, wrong types, YAML aliases, deep
nesting, binary and cut-off files, huge and tiny numbers, duplicate keys.
Each goes through the real command line (``belt_drive_ros.cli.main``, a few
as a subprocess). Outcomes:

* ``error``: exit 2 (bad input) or 1 (failed run, e.g. a diverging state),
  exactly one ``belt-drive: error:`` line, no traceback;
* ``run``: exit 0;
* a **crash** is a traceback or the CLI's "internal error" line; a **hang**
  is a mutant that takes longer than :data:`BUDGET_S` (interrupted by a
  timer); **silent wrong** is exit 0 for a mutant that must be refused
  (a required key dropped, a number given as text, an alias, a duplicate
  key, nesting, an absurd value of a parameter or time setting).
"""

from __future__ import annotations

import collections
import os
import random
import signal
import subprocess
import sys

import pytest
import yaml

from belt_drive_ros.cli import main
from belt_drive_ros.core.params import OPTIONAL_DEFAULTS
from belt_drive_ros.core.scene import REQUIRED_KEYS, load_scene

SCENES = ("paper", "truck_compressor", "e_motor_start", "bsg_start")
#: seconds one mutant may take (the runs are cut to 20 ms of simulated time)
BUDGET_S = 20.0


class _Hang(BaseException):
    """Raised by the timer: a mutant ran past its budget."""


def _dump(data) -> str:
    return yaml.safe_dump(data, sort_keys=False)


class _Quoting(yaml.SafeDumper):
    """Writes every string quoted: a mutant's text value stays text for any YAML version (1e3 is a number in 1.2)."""


_Quoting.add_representer(str, lambda dumper, value: dumper.represent_scalar("tag:yaml.org,2002:str", value, style="'"))


def _quoted(data) -> bytes:
    return yaml.dump(data, Dumper=_Quoting, sort_keys=False).encode()


def _mutants(seed: int = 13):
    """(category, must_fail, label, file bytes) of every mutant."""
    rng = random.Random(seed)
    for name in SCENES:
        base = load_scene(name).to_dict()
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


MUTANTS = list(_mutants())


def _run_one(path, capsys):
    def alarm(signum, frame):
        raise _Hang()

    old = signal.signal(signal.SIGALRM, alarm)
    signal.setitimer(signal.ITIMER_REAL, BUDGET_S)
    try:
        code = main(["sim", str(path), "--quiet", "--duration", "0.02"])
        hang = False
    except _Hang:
        code, hang = None, True
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)
    captured = capsys.readouterr()
    return code, hang, captured.err


def test_every_scene_mutant_is_a_clean_error_or_a_run(tmp_path, capsys):
    table = collections.defaultdict(collections.Counter)
    problems = []
    for category, must_fail, label, data in MUTANTS:
        path = tmp_path / "mutant.yaml"
        path.write_bytes(data)
        code, hang, err = _run_one(path, capsys)
        lines = err.strip().splitlines()
        crash = "Traceback" in err or "internal error" in err
        one_line = code == 0 or (len(lines) == 1 and lines[0].startswith("belt-drive: error: ") and len(lines[0]) < 500)
        if hang:
            outcome = "hang"
        elif crash or code not in (0, 1, 2) or not one_line:
            outcome = "crash"
        elif code == 0 and must_fail:
            outcome = "silent wrong"
        else:
            outcome = "clean error" if code else "run"
        table[category][outcome] += 1
        table[category]["tried"] += 1
        if outcome in ("hang", "crash", "silent wrong"):
            problems.append(f"{outcome}: {category} [{label}] exit {code}: {err.strip()[:300]}")
    report = "\n".join(f"{c:12s} " + ", ".join(f"{k} {v}" for k, v in sorted(t.items())) for c, t in sorted(table.items()))
    print(report)
    assert not problems, "\n".join(problems[:20]) + "\n" + report
    assert sum(t["tried"] for t in table.values()) == len(MUTANTS) > 400


@pytest.mark.parametrize("label", ["paper billion laughs", "paper nest 100000", "paper random 0", "paper -params.I_M"])
def test_mutants_through_the_installed_entry_point(tmp_path, label):
    data = next(d for _, _, lab, d in MUTANTS if lab == label)
    path = tmp_path / "mutant.yaml"
    path.write_bytes(data)
    proc = subprocess.run(
        [sys.executable, "-m", "belt_drive_ros.cli", "sim", str(path), "--quiet"],
        capture_output=True, text=True, timeout=120, env={**os.environ, "PYTHONPATH": os.getcwd()},
    )
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.count("\n") == 1 and proc.stderr.startswith("belt-drive: error: ") and "Traceback" not in proc.stderr
