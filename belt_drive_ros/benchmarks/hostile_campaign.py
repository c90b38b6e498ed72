"""Hostile campaign files and bag folders: the seeded mutants behind two categories of ``belt-drive bench hostile``.

The generators of two categories of :mod:`belt_drive_ros.benchmarks.hostile`
(which runs them: ``run_campaign_files``, ``run_bag_folders``), shared with
``tests/test_fuzz_campaigns.py``:

* ``campaign file``: :func:`campaign_mutants`, mutants of three small
  campaigns (grid + Monte Carlo, profiles, fleet) and special files, each
  through the real entry point ``belt-drive sweep FILE --check``
  (validation, the up-front limits, the variant table, and up to 8
  variants run in this process as a worker runs them, their rows written as
  a Parquet part): fast, no cluster. ``must_fail`` mutants must not exit 0;
  where the mutant states how many variants it has, a different count is
  **silent wrong**;
* ``bag folder``: :func:`bag_folder_mutants`, a split rosbag2 folder
  (``metadata.yaml`` + three MCAP files) with its ``metadata.yaml`` or its
  files damaged, through ``msg-tools info``, ``export`` and ``compare``
  against the intact folder (``hostile.write_bag_folder``), classified as
  the MCAP file mutants are.
"""

from __future__ import annotations

import os
import random
import shutil
from pathlib import Path

import yaml

#: a small grid + Monte Carlo campaign (2 x 3 = 6 variants of 50 ms)
GRID_MC = {
    "name": "fuzz_grid",
    "scene": "paper",
    "set": {"duration": 0.05},
    "grid": {"params.k": [1.5e4, 2.5e4]},
    "monte_carlo": {
        "samples": 3, "seed": 1,
        "vary": {"params.I_3": {"uniform": [0.9, 1.1]}, "params.F_0": {"normal": [400.0, 10.0], "absolute": True}},
    },
    "metrics": ["peak_belt_torque", "min_slack_force"],
    "limits": {"min_slack_force": 0.0},
}  # fmt: skip
#: profiles instead of a Monte Carlo (2 variants)
PROFILES = {
    "scene": "paper",
    "set": {"duration": 0.05, "model": "flexible"},
    "profiles": [{"load": {"type": "polynomial", "c0": 0.0, "c1": 0.02, "c2": 0.0002}}, {"load": 1.0}],
}
#: a fleet of the folder ``fleet/`` beside the file (two copies of a shipped torque recording)
FLEET = {"scene": "SCENE", "set": {"duration": 0.05}, "fleet": {"folder": "fleet"}}
BAGS = Path(__file__).resolve().parents[2] / "bags"


class _Quoting(yaml.SafeDumper):
    """Every string quoted: a mutant's text stays text (``'1e3'``, ``'false'``)."""


_Quoting.add_representer(str, lambda d, v: d.represent_scalar("tag:yaml.org,2002:str", v, style="'"))


def dump_campaign(data) -> bytes:
    """``data`` as YAML with every string quoted (a mutant's text stays text)."""
    return yaml.dump(data, Dumper=_Quoting, sort_keys=False).encode()


def _with(base: dict, path: str, value) -> dict:
    """A deep copy of ``base`` with ``path`` (dots between mapping keys) set to ``value`` (``DELETE``: removed)."""
    import copy

    out = copy.deepcopy(base)
    node = out
    parts = path.split("/")
    for part in parts[:-1]:
        node = node.setdefault(part, {})
    if value is DELETE:
        node.pop(parts[-1], None)
    else:
        node[parts[-1]] = value
    return out


DELETE = object()
TEXT = "x" * 100_000


def campaign_mutants(seed: int = 24):
    """(category, must_fail, label, file bytes, variants or None, setup) of every campaign-file mutant (seeded).

    ``variants``: the number a valid mutant expands to (checked against what
    ``--check`` reports). ``setup``: how the fleet folder beside the file is
    made (``"fleet"``: two recordings; ``"empty"``; ``"fifo"``: ``x.mcap`` a
    FIFO; ``"other"``: a non-MCAP file only), or ``None``.
    """
    rng = random.Random(seed)
    base = GRID_MC
    bad_values = ("12", "1e3", [1.0], {"x": 1}, True, 5, 2.7, TEXT)
    # every top-level key given the wrong type; null means "not given" for the optional keys
    for key in ("name", "scene", "set", "grid", "profiles", "monte_carlo", "metrics", "limits", "description", "fleet"):
        for bad in bad_values:
            ok = (key in ("name", "description") and isinstance(bad, str) and len(bad) < 100
                  ) or (key == "scene" and bad == "12")  # fmt: skip
            if key == "scene" and bad == "12":
                continue  # an unknown scene name: refused anyway, listed below
            yield "wrong type", not ok, f"{key}={str(bad)[:12]!r}", dump_campaign(_with(base, key, bad)), 6 if ok else None, None
        optional = key in ("name", "set", "grid", "profiles", "monte_carlo", "metrics", "limits", "description", "fleet")
        count = {"grid": 3, "monte_carlo": 2}.get(key, 6)
        yield "wrong type", not optional, f"{key}=null", dump_campaign(_with(base, key, None)), count if optional else None, None
    # Monte Carlo: counts, seeds, distributions
    for value, count in (("many", None), (float("inf"), None), ([1], None), (2.7, None), (-1, None), (0, None), (True, None),
                         (None, None), (1e9, None), (1e3, 2000), (4.0, 8), ("4", None)):
        yield "monte carlo", count is None, f"samples={value!r}", dump_campaign(_with(base, "monte_carlo/samples", value)), count, None
    for value, count in ((-1, None), (2.5, None), ("x", None), (2**64, None), (1e3, 6), (None, None), (0, 6)):
        data = dump_campaign(_with(base, "monte_carlo/seed", value)) if value != 2**64 else (
            yaml.safe_dump(base, sort_keys=False).replace("seed: 1", f"seed: {2**64}").encode())
        yield "monte carlo", count is None, f"seed={value!r}", data, count, None
    vary = "monte_carlo/vary/params.I_3"
    for spec in ({"normal": [1, "x"]}, {"normal": "x"}, {"normal": [1]}, {"normal": [1, 2, 3]}, {"normal": -0.1},
                 {"normal": float("inf")}, {"normal": [0.0, -1.0]}, {"normal": [1e308, 1e308], "absolute": True},
                 {"uniform": [-1e308, 1e308]}, {"uniform": [2, 1]}, {"uniform": "x"}, {"uniform": [1]},
                 {"uniform": [float("nan"), 1]}, {"uniform": [0.9, 1.1], "absolute": "false"},
                 {"uniform": [0.9, 1.1], "absolute": "yes"}, {"uniform": [0.9, 1.1], "absolute": 1}, {"gauss": 0.1},
                 {}, {"normal": 0.1, "uniform": [0.9, 1.1]}, {"normal": 0.1, "absolute": True}, 0.1, [0.9, 1.1]):
        yield "monte carlo", True, f"vary {spec!r}"[:60], dump_campaign(_with(base, vary, spec)), None, None
    for spec, count in (({"normal": 0.0}, 6), ({"uniform": [1.0, 1.0]}, 6), ({"normal": [0.1, 0.0], "absolute": True}, 6),
                        ({"uniform": [0.9, 1.1], "absolute": False}, 6)):
        yield "monte carlo", False, f"vary {spec!r}"[:60], dump_campaign(_with(base, vary, spec)), count, None
    yield "monte carlo", True, "vary {}", dump_campaign(_with(base, "monte_carlo/vary", {})), None, None
    yield "monte carlo", True, "monte_carlo.bogus", dump_campaign(_with(base, "monte_carlo/bogus", 1)), None, None
    # key paths and semantics
    for key in ("params.kk", "a.b.c", "drive", "params.", "", "k.k"):
        yield "key path", True, f"grid {key!r}", dump_campaign(_with(base, f"grid/{key}", [1.0])), None, None
    yield "key path", True, "grid 5: [1]", yaml.safe_dump({**base, "grid": {5: [1.0]}}).encode(), None, None
    yield "key path", True, "grid and vary: params.k", dump_campaign(_with(base, "monte_carlo/vary/params.k", {"normal": 0.05})), None, None
    yield "key path", True, "grid and vary: k and params.k", dump_campaign(_with(base, "monte_carlo/vary/k", {"normal": 0.05})), None, None
    yield "key path", True, "grid k and params.k", dump_campaign(_with(base, "grid/k", [1.0e4])), None, None
    yield "key path", True, "vary I_3 and params.I_3", dump_campaign(_with(base, "monte_carlo/vary/I_3", {"normal": 0.1})), None, None
    yield "key path", True, "vary drive.type (text base)", dump_campaign(_with(base, "monte_carlo/vary/drive.type", {"normal": 0.1})), None, None
    for values in ([], 5, "x", {"a": 1}):
        yield "key path", True, f"grid params.k={values!r}", dump_campaign(_with(base, "grid/params.k", values)), None, None
    # grids whose variants fail one by one: a row each (exit 1), never an abort
    for values in (["nosuch", 7, None], [["a"], {"b": 1}, "rk4"], [True, 1.5, "x"]):
        yield "variant rows", False, f"grid method={values!r}", dump_campaign(_with(base, "grid", {"method": values})), len(values) * 3, None
    yield "variant rows", False, "grid params.k=[-5, 2e4, .nan]", dump_campaign(_with(base, "grid", {"params.k": [-5.0, 2e4, float("nan")]})), 9, None
    yield "variant rows", False, "grid drive.nosuch=[1, 2]", dump_campaign(_with(base, "grid", {"drive.nosuch": [1, 2]})), 6, None
    yield "variant rows", False, "set method=nosuch", dump_campaign(_with(base, "set/method", "nosuch")), None, None
    # sizes beyond the machine: refused up front with an estimate
    yield "limits", True, "grid of 1e7 points", dump_campaign(_with(base, "grid", {f"params.{k}": [1.0 + j * 1e-3 for j in range(57)]
                                                                           for k in ("k", "c", "F_0", "mu")})), None, None
    yield "limits", True, "samples 1e9", dump_campaign(_with(base, "monte_carlo/samples", 10**9)), None, None
    yield "limits", True, "samples 2e6", dump_campaign(_with(base, "monte_carlo/samples", 2_000_000)), None, None
    yield "limits", False, "samples 50000", dump_campaign(_with(base, "monte_carlo/samples", 50_000)), 100_000, None
    # metrics and limits
    for value in (5, [], ["nosuch"], ["peak_belt_torque", "peak_belt_torque"], "x", [5]):
        yield "metrics", True, f"metrics={value!r}", dump_campaign(_with(base, "metrics", value)), None, None
    for value in ([1], {"nosuch": 1}, {"min_slack_force": "x"}, {"min_slack_force": float("inf")}, {"min_slack_force": True}):
        yield "metrics", True, f"limits={value!r}", dump_campaign(_with(base, "limits", value)), None, None
    # profiles and set
    for value, count in ((5, None), ([5], None), ([{}], None), ([{"drive": 5.0}], 1), ([{"drive": {"type": "nosuch"}}], None),
                         ([{"bogus": 1}], None), ([{"load": {"type": "polynomial", "c0": "x"}}], None)):
        yield "profiles", count is None, f"profiles={value!r}"[:60], dump_campaign(_with(PROFILES, "profiles", value)), count, None
    yield "profiles", False, "profiles", dump_campaign(PROFILES), 2, None
    for value in ({"k": -1.0}, {"dt": "x"}, {"nosuch": 1}, {"params.k": "2e4"}, [1], {"duration": float("nan")}):
        yield "set", True, f"set={value!r}", dump_campaign(_with(base, "set", value)), None, None
    yield "set", False, "set params.k=1.5e4 (a number in YAML 1.2)", yaml.safe_dump(base, sort_keys=False).replace(
        "duration: 0.05", "duration: 0.05\n  params.k: 1.5e4").encode(), 6, None
    for value in (5, "", "nosuch", "no/such.yaml", "/dev/zero", {}, {"extends": "nosuch"}):
        yield "scene", True, f"scene={value!r}", dump_campaign(_with(base, "scene", value)), None, None
    yield "scene", False, "scene={extends: paper} inline", dump_campaign(_with(base, "scene", {"extends": "paper"})), 6, None
    # fleets
    fleet = dict(FLEET, scene=str(BAGS / "engine_idle.yaml"))
    yield "fleet", False, "fleet of 2", dump_campaign(fleet), 2, "fleet"
    for label, setup in (("empty folder", "empty"), ("x.mcap a FIFO", "fifo"), ("no .mcap files", "other")):
        yield "fleet", True, label, dump_campaign(fleet), None, setup
    for folder in ("/dev", "/proc/self", "no/such", "/dev/null"):
        yield "fleet", True, f"folder {folder}", dump_campaign(_with(fleet, "fleet/folder", folder)), None, "fleet"
    for value in (5, {"golden": "fleet"}, [1], {"folder": 5}, {"folder": "fleet", "bogus": 1}):
        yield "fleet", True, f"fleet={value!r}", dump_campaign(_with(fleet, "fleet", value)), None, "fleet"
    yield "fleet", True, "fleet golden missing", dump_campaign(_with(fleet, "fleet/golden", "nosuch")), None, "fleet"
    yield "fleet", True, "fleet and grid", dump_campaign(_with(fleet, "grid", {"params.k": [1e4]})), None, "fleet"
    # YAML itself: aliases, nesting, duplicates, binary, cut-off files
    text = yaml.safe_dump(base, sort_keys=False)
    bomb = "a: &a [x,x,x,x,x,x,x,x,x]\n" + "".join(
        f"{chr(98 + i)}: &{chr(98 + i)} [" + ",".join([f"*{chr(97 + i)}"] * 9) + "]\n" for i in range(8))
    yield "yaml", True, "billion laughs", (bomb + text).encode(), None, None
    yield "yaml", True, "alias", text.replace("seed: 1", "seed: &s 1\n  other: *s", 1).encode(), None, None
    yield "yaml", True, "anchor", text.replace("samples: 3", "samples: &n 3", 1).encode(), None, None
    yield "yaml", True, "merge key", text.replace("monte_carlo:\n", "monte_carlo:\n  <<: {samples: 2}\n", 1).encode(), None, None
    for depth in (40, 1000, 100_000):
        yield "yaml", True, f"nest {depth}", (text + "description: " + "[" * depth + "]" * depth + "\n").encode(), None, None
    lines = text.splitlines(keepends=True)
    for line in [ln for ln in lines if ln[:1].isalpha()][:4]:
        yield "yaml", True, f"duplicate {line.split(':')[0]}", (text + line).encode(), None, None
    yield "yaml", True, "two documents", (text + "---\n" + text).encode(), None, None
    raw = text.encode()
    for i in range(6):
        yield "yaml", True, f"random {i}", bytes(rng.randrange(256) for _ in range(rng.randrange(1, 3000))), None, None
    yield "yaml", True, "latin-1", text.replace("fuzz_grid", "caf\xe9").encode("latin-1"), None, None
    yield "yaml", True, "empty", b"", None, None
    yield "yaml", True, "NUL", b"\x00" * 64, None, None
    for i in range(16):
        b = bytearray(raw)
        for _ in range(rng.randrange(1, 4)):
            b[rng.randrange(len(b))] = rng.randrange(256)
        yield "yaml", False, f"flip {i}", bytes(b), None, None
    for cut in sorted(rng.sample(range(1, len(raw)), 16)):
        yield "yaml", False, f"cut {cut}", raw[:cut], None, None


def make_fleet(folder: Path, setup: str | None) -> None:
    """The fleet folder a mutant's ``setup`` asks for (see :func:`campaign_mutants`)."""
    if setup is None:
        return
    fleet = folder / "fleet"
    fleet.mkdir()
    if setup == "fleet":
        for k in range(2):
            shutil.copy(BAGS / "engine_idle_torque.mcap", fleet / f"truck_{k}.mcap")
    elif setup == "fifo":
        shutil.copy(BAGS / "engine_idle_torque.mcap", fleet / "a.mcap")
        os.mkfifo(fleet / "x.mcap")
    elif setup == "other":
        (fleet / "notes.txt").write_text("no recordings here\n")


def special_campaign_files(tmp: Path):
    """(label, path) of files that are not campaign files: a device, a FIFO, a folder, sparse 20 GB and 50 MB files."""
    fifo = tmp / "campaign.fifo"
    os.mkfifo(fifo)
    folder = tmp / "folder.yaml"
    folder.mkdir()
    out = [("/dev/zero", Path("/dev/zero")), ("a FIFO", fifo), ("a folder", folder)]
    for label, size in (("sparse 20 GB", 20 * 2**30), ("50 MB", 50 * 2**20), ("2 MiB", 2 * 2**20)):
        path = tmp / f"{label.replace(' ', '_')}.yaml"
        with open(path, "wb") as f:
            f.write(b"scene: paper\n# ")
            f.truncate(size)  # sparse: no disk used
        out.append((label, path))
    return out


# ------------------------------------------------------------------ bag folders
def bag_folder_mutants(folder: Path, seed: int = 24):
    """(label, change) of every bag-folder mutant: ``change(copy)`` damages a copy of the intact ``folder``."""
    rng = random.Random(seed)
    meta_text = (folder / "metadata.yaml").read_text()
    files = sorted(p.name for p in folder.glob("*.mcap"))

    def meta(text):
        return lambda d: (d / "metadata.yaml").write_bytes(text if isinstance(text, bytes) else text.encode())

    def replace_meta(old, new):
        return meta(meta_text.replace(old, new, 1))

    bomb = "a: &a [x,x,x,x,x,x,x,x,x]\n" + "".join(
        f"{chr(98 + i)}: &{chr(98 + i)} [" + ",".join([f"*{chr(97 + i)}"] * 9) + "]\n" for i in range(8))
    yield "metadata billion laughs", meta(bomb + meta_text)
    for key in ("relative_file_paths", "files"):  # the expansion where the reader walks it
        yield f"metadata billion laughs in {key}", meta(bomb + meta_text.replace(f"  {key}:", f"  {key}: *i\n  old_{key}:", 1))
    yield "metadata alias", meta(meta_text.replace("rosbag2_bagfile_information:", "x: &x 1\nrosbag2_bagfile_information:", 1))
    for depth in (40, 100_000):
        yield f"metadata nest {depth}", meta(meta_text + "extra: " + "[" * depth + "]" * depth + "\n")
    yield "metadata duplicate key", meta(meta_text + "rosbag2_bagfile_information: {}\n")
    yield "metadata empty", meta(b"")
    yield "metadata NUL", meta(b"\x00" * 64)
    yield "metadata latin-1", meta(meta_text.encode() + "# caf\xe9\n".encode("latin-1"))
    yield "metadata a list", meta("[1, 2]\n")
    yield "metadata removed", lambda d: (d / "metadata.yaml").unlink()

    def sparse(d):
        with open(d / "metadata.yaml", "wb") as f:
            f.truncate(20 * 2**30)

    yield "metadata sparse 20 GB", sparse

    def fifo(d):
        (d / "metadata.yaml").unlink()
        os.mkfifo(d / "metadata.yaml")

    yield "metadata a FIFO", fifo

    def devzero(d):
        (d / "metadata.yaml").unlink()
        os.symlink("/dev/zero", d / "metadata.yaml")

    yield "metadata -> /dev/zero", devzero
    yield "relative_file_paths 5", replace_meta("relative_file_paths:", "relative_file_paths: 5\n  old_paths:")
    yield "files 5", replace_meta("  files:", "  files: 5\n  old_files:")
    for name in files:
        yield f"{name} listed as nope.mcap", replace_meta(name, "nope.mcap")
    lines = meta_text.splitlines(keepends=True)
    counts = [i for i, ln in enumerate(lines) if ln.strip().startswith("message_count:") and ln.split(":")[1].strip().isdigit()]
    for i in counts:
        yield f"count on line {i + 1} + 1", meta("".join(
            ln if j != i else ln.replace(ln.split(":")[1].strip(), str(int(ln.split(":")[1]) + 1)) for j, ln in enumerate(lines)))
        yield f"count on line {i + 1} 'x'", meta("".join(ln if j != i else ln.split(":")[0] + ": x\n" for j, ln in enumerate(lines)))
        yield f"count on line {i + 1} .inf", meta("".join(ln if j != i else ln.split(":")[0] + ": .inf\n" for j, ln in enumerate(lines)))
    raw = meta_text.encode()
    for i in range(8):
        b = bytearray(raw)
        for _ in range(rng.randrange(1, 4)):
            b[rng.randrange(len(b))] = rng.randrange(256)
        yield f"metadata flip {i}", meta(bytes(b))
    for cut in sorted(rng.sample(range(1, len(raw)), 8)):
        yield f"metadata cut {cut}", meta(raw[:cut])
    for name in files:
        yield f"{name} removed", lambda d, n=name: (d / n).unlink()
        yield f"{name} emptied", lambda d, n=name: (d / n).write_bytes(b"")

        def to_fifo(d, n=name):
            (d / n).unlink()
            os.mkfifo(d / n)

        yield f"{name} a FIFO", to_fifo
        yield f"{name} cut in half", lambda d, n=name: (d / n).write_bytes((d / n).read_bytes()[: (d / n).stat().st_size // 2])
    yield "a split file copied in twice", lambda d: shutil.copy(d / files[0], d / "copy_9.mcap")
    yield "no metadata, a file copied in twice", lambda d: ((d / "metadata.yaml").unlink(), shutil.copy(d / files[0], d / "copy_9.mcap"))


# ------------------------------------------------------------------ whole sweeps (a cluster each)
#: a campaign long enough to interrupt (200,000 runs of paper: minutes on two workers)
LONG = {"scene": "paper", "monte_carlo": {"samples": 200_000, "seed": 1, "vary": {"params.k": {"normal": 0.05}}}}


def _sweep(path: Path, *args, signal_after_part=None, group: bool = False, timeout: float = 300.0):
    """(exit status or None for a hang, stderr) of ``belt-drive sweep PATH --quiet ARGS`` in a child process (its own
    process group); ``signal_after_part``: a signal sent (to the group with ``group``) once a part is written."""
    import signal
    import subprocess
    import sys
    import time

    cmd = [sys.executable, "-m", "belt_drive_ros.cli", "sweep", str(path), "--quiet", *map(str, args)]
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[2])}
    child = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=env,
                             start_new_session=True, preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        if signal_after_part is not None:
            parts = path.with_suffix(".campaign") / "parts"
            deadline = time.monotonic() + timeout
            while not (parts.is_dir() and any(parts.glob("part-*.parquet"))):
                if child.poll() is not None or time.monotonic() > deadline:
                    break
                time.sleep(0.1)
            if child.poll() is None:
                (os.killpg if group else os.kill)(child.pid, signal_after_part)
        err = child.communicate(timeout=timeout)[1]
        return child.returncode, err
    except subprocess.TimeoutExpired:
        return None, "no exit within the budget"
    finally:
        if child.poll() is None:
            os.killpg(child.pid, signal.SIGKILL)
            child.wait()
        deadline = time.monotonic() + 30.0  # the workers and the resource tracker end with the command
        while _group_alive(child.pid) and time.monotonic() < deadline:
            time.sleep(0.2)


def _group_alive(pgid: int) -> bool:
    try:
        os.killpg(pgid, 0)
        return True
    except ProcessLookupError:
        return False
    except PermissionError:
        return True


def run_campaign_runs(table, tmp: Path, quick: bool) -> None:
    """Whole sweeps through ``belt-drive sweep`` in child processes: a grid of bad methods (a failing row
    each, exit 1), Ctrl-C to the process group and SIGTERM (exit 130 / 143, one line, nothing left running,
    the parts kept), SIGKILL then the same command (resumes to the whole table, no warning), a fleet resumed
    after a recording was renamed (refused). Category ``campaign run``."""
    import signal

    import pandas as pd

    category = "campaign run"
    bad = tmp / "methods.yaml"
    bad.write_bytes(dump_campaign({"scene": "paper", "set": {"duration": 0.05}, "grid": {"method": ["nosuch", 7, None, "etd2"]}}))
    status, err = _sweep(bad, "--workers", "1")
    result = bad.with_suffix(".campaign") / "results.parquet"
    if status is None:
        outcome = "hang"
    elif status == 1 and result.is_file():
        rows = pd.read_parquet(result)
        errors = [e != "" for e in rows["error"]]
        outcome = "clean error" if errors == [True, True, True, False] and len(err.strip().splitlines()) == 0 else "silent wrong"
    else:
        outcome = "crash"
    table.add(category, outcome, "grid method [nosuch, 7, null, etd2]: a row each, exit 1", err)
    # (--quick: neither; tests/test_campaign.py sends both to the same sweep and checks the same outcome, more closely)
    signals = [(signal.SIGINT, True), (signal.SIGTERM, False)] if not quick else []
    for sig, group in signals:
        long = tmp / f"long_{sig.name}.yaml"
        long.write_bytes(dump_campaign(LONG))
        status, err = _sweep(long, "--workers", "2", signal_after_part=sig, group=group)
        lines = err.strip().splitlines()
        kept = any((long.with_suffix(".campaign") / "parts").glob("part-*.parquet"))
        if status is None:
            outcome = "hang"
        elif status == 128 + sig and len(lines) == 1 and lines[0].startswith(f"belt-drive: interrupted by {sig.name}"):
            outcome = "clean error" if kept else "data lost"
        else:
            outcome = "crash"
        table.add(category, outcome, f"{sig.name} to the {'process group' if group else 'command'} mid-run", err)
    if quick:
        return
    long = tmp / "long_kill.yaml"
    small = dict(LONG, monte_carlo=dict(LONG["monte_carlo"], samples=20_000))
    long.write_bytes(dump_campaign(small))
    status, err = _sweep(long, "--workers", "2", signal_after_part=signal.SIGKILL)
    noise = err.strip().splitlines()
    status, err = _sweep(long, "--workers", "2")
    result = long.with_suffix(".campaign") / "results.parquet"
    if status is None:
        outcome = "hang"
    elif noise or err.strip():
        outcome = "crash"  # a leaked-semaphore warning after the kill, or an error on resume
    elif status == 0 and result.is_file() and sorted(pd.read_parquet(result)["variant"]) == list(range(20_000)):
        outcome = "ok"
    else:
        outcome = "data lost"
    table.add(category, outcome, "SIGKILL mid-run, then the same command resumes", " ".join(noise) + err)
    folder = tmp / "fleet_resume"
    folder.mkdir()
    make_fleet(folder, "fleet")
    shutil.copy(BAGS / "engine_idle_torque.mcap", folder / "fleet" / "truck_2.mcap")
    fleet = folder / "fleet.yaml"
    fleet.write_bytes(dump_campaign(dict(FLEET, scene=str(BAGS / "engine_idle.yaml"))))
    _sweep(fleet, "--workers", "1", "--batch-size", "1", signal_after_part=signal.SIGTERM)
    (folder / "fleet" / "truck_1.mcap").rename(folder / "fleet" / "truck_7.mcap")
    status, err = _sweep(fleet, "--workers", "1", "--batch-size", "1")
    lines = err.strip().splitlines()
    if status is None:
        outcome = "hang"
    elif status == 2 and len(lines) == 1 and "another campaign" in lines[0]:
        outcome = "clean error"
    elif status == 0:
        outcome = "silent wrong"  # old parts of a renamed recording reused
    else:
        outcome = "crash"
    table.add(category, outcome, "fleet resumed after a recording was renamed", err)
