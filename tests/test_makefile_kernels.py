"""``make`` compiles the kernels again whenever their cached machine code is dropped.

:mod:`~belt_drive_ros.core.jit_cache` drops a kernel file's cache entries when that file or any package module it
imports (transitively: ``profile_data``'s kind codes, ``model``, ``stepper`` ...) changes. The Makefile's stamp that
warms the kernels (so a first run compiles nothing) must depend on each of those sources: it listed only the
``kernel*.py``, ``tick.py`` and ``network`` files, so a change to e.g. ``profile_data.py`` dropped the cache and the
next ``make test`` compiled for minutes inside the suite.
"""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest

from belt_drive_ros.core import jit_cache

ROOT = Path(__file__).resolve().parents[1]


def _database() -> str:
    """``make -pn``'s database of the Makefile (variables expanded, rules with their prerequisites)."""
    done = subprocess.run(["make", "-pn", "-f", "Makefile", "help"], cwd=ROOT, capture_output=True, text=True,
                          timeout=60)  # fmt: skip
    assert done.returncode == 0, done.stderr
    return done.stdout


@pytest.mark.skipif(shutil.which("make") is None, reason="needs make")
def test_the_warming_stamp_depends_on_every_source_the_kernel_cache_is_stamped_with():
    db = _database()
    kernels = set(re.search(r"^KERNELS :?= (.*)$", db, re.M).group(1).split())
    cached = [p for folder in (jit_cache.CORE, jit_cache.CORE / "network") for p in sorted(folder.glob("*.py"))
              if "cache=True" in p.read_text()]  # fmt: skip
    assert cached
    needed = {str(f.relative_to(ROOT)) for p in cached for f in jit_cache._closure(p)}
    assert needed <= kernels, sorted(needed - kernels)
    # the kernels are warmed by a rule that has them as prerequisites
    warm = [block for block in db.split("\n\n") if "warm(jobs=" in block]
    assert warm and all(f in warm[0] for f in needed)
