"""``belt-drive bench compile``: how long the numba kernels take to build from an empty cache.

``make install`` compiles every kernel once into numba's disk cache (:mod:`belt_drive_ros.core.warm`), and a
fresh clone's ``make test`` waits for it. This study builds them again in a child process whose
``NUMBA_CACHE_DIR`` is a new empty folder (the tree's own cache is not touched):

* every kernel in one process (``warm()``, jobs=1), each function's build timed by a listener on numba's
  ``numba:compile`` event (a build includes the builds of the callees it compiles, so nested times add up to
  more than the wall time);
* then ``warm(jobs=2)``, as ``make install`` runs it, in a second empty folder: its wall time.

``--quick`` builds the torque dispatcher's two entries only (``profile_torque``, ``profile_torque_array``; for
tests). ``--baseline DIR`` (another checkout): the same in a child process of that tree, after this tree's, in
the same run. The figures are wall times of one build each on a shared machine: a second run differs by some
percent; a build whose time doubles is a change of the code.

Why a build can be slow: numba's IR inliner (``inline="always"``) copies a callee block by block, each block's
copy taking every variable of the callee's scope with it, at every site (``docs/development.md``, Inline or
call).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from .common import tree_python, write_csv

#: the child: builds into a new empty NUMBA_CACHE_DIR, prints the package file it ran, then one JSON line
_CHILD = r"""
import json, os, shutil, sys, tempfile, time
cache = tempfile.mkdtemp(prefix="belt-drive-compile-")
os.environ["NUMBA_CACHE_DIR"] = cache  # (before numba is imported: its config reads it once)
try:
    import numba.core.event as ev
    builds, started = [], {}

    class Builds(ev.Listener):
        def on_start(self, event):
            started[id(event.data)] = time.perf_counter()

        def on_end(self, event):
            took = time.perf_counter() - started.pop(id(event.data), time.perf_counter())
            function = getattr((event.data or {}).get("dispatcher"), "py_func", None)
            if function is not None:
                builds.append((f"{function.__module__.rsplit('.', 1)[-1]}.{function.__qualname__}", took))

    ev.register("numba:compile", Builds())
    import belt_drive_ros
    from belt_drive_ros.core import warm
    start = time.perf_counter()
    if sys.argv[1] == "quick":
        import numpy as np
        from belt_drive_ros.core.sources import Engine
        engine = Engine()
        engine.torque(0.1, 1.0, 2.0)
        engine.torque(np.array([0.1, 0.2]), 1.0, 2.0)
    else:
        warm.warm(jobs=1)
    wall = time.perf_counter() - start
    figures = {"wall": wall, "builds": builds}
    if sys.argv[1] != "quick":
        shutil.rmtree(cache, ignore_errors=True)
        os.makedirs(cache)
        start = time.perf_counter()
        import subprocess
        subprocess.run([sys.executable, "-c", "from belt_drive_ros.core.warm import warm; warm(jobs=2)"], check=True,
                       env=dict(os.environ))
        figures["jobs2"] = time.perf_counter() - start
finally:
    shutil.rmtree(cache, ignore_errors=True)
print(belt_drive_ros.__file__)
print(json.dumps(figures))
"""

#: builds shorter than this [s] are summed into one line (numba's own helpers, small kernels)
SHOWN = 1.0


def _build(root: Path, mode: str) -> dict:
    """The child's figures for the checkout ``root`` (``PYTHONPATH`` = it, the cwd a scratch folder: ``-c``
    imports from the cwd first); a child that ran another tree's package raises."""
    with tempfile.TemporaryDirectory() as tmp:
        env = dict(os.environ, PYTHONPATH=str(root), MPLBACKEND="Agg")
        done = subprocess.run([tree_python(root), "-c", _CHILD, mode], cwd=tmp, env=env, capture_output=True, text=True)
    if done.returncode != 0:
        tail = (done.stderr.strip().splitlines() or ["(no output)"])[-1]
        raise RuntimeError(f"bench compile: the build in {root} failed (exit {done.returncode}): {tail}")
    lines = done.stdout.strip().splitlines()
    if not Path(lines[-2]).resolve().is_relative_to(root):
        raise RuntimeError(f"bench compile: {root} ran {lines[-2]}")
    return json.loads(lines[-1])


def _report(label: str, figures: dict) -> list[dict]:
    """Print one tree's figures; its CSV rows."""
    builds = sorted(figures["builds"], key=lambda b: -b[1])
    shown = [b for b in builds if b[1] >= SHOWN]
    rest = builds[len(shown):]
    print(f"  {label}: every build from an empty cache, in one process (a build includes the callees it compiles)")
    for name, took in shown:
        print(f"    {name:<52} {took:7.1f} s")
    print(f"    {f'{len(rest)} builds under {SHOWN:g} s':<52} {sum(b[1] for b in rest):7.1f} s")
    print(f"    {'wall, one process':<52} {figures['wall']:7.1f} s")
    rows = [{"tree": label, "what": name, "seconds": round(took, 3)} for name, took in builds]
    rows.append({"tree": label, "what": "wall, one process", "seconds": round(figures["wall"], 3)})
    if "jobs2" in figures:
        print(f"    {'wall, warm(jobs=2) as make install runs it':<52} {figures['jobs2']:7.1f} s")
        rows.append({"tree": label, "what": "wall, warm(jobs=2)", "seconds": round(figures["jobs2"], 3)})
    return rows


def run(out: Path, quick: bool = False, baseline: Path | None = None) -> dict:
    """Build this tree's kernels (and ``baseline``'s) from empty caches; print and write ``compile.csv``."""
    mode = "quick" if quick else "all"
    here = Path(__file__).resolve().parents[2]
    print("bench compile: " + ("the torque dispatcher's entries only (--quick)" if quick else
          "every kernel, then warm(jobs=2): a few minutes per tree"), flush=True)  # fmt: skip
    rows = _report("this tree", _build(here, mode))
    if baseline is not None:
        rows += _report(f"baseline {baseline}", _build(Path(baseline).resolve(), mode))
    path = write_csv(Path(out) / "compile.csv", rows, ("tree", "what", "seconds"))
    sys.stdout.flush()
    return {"csv": path, "rows": rows}
