"""The campaign files in examples/ run as the docs show them, made small.

Each test copies examples/ and bags/ into a temporary folder (the layout the
files refer to: ``../bags/engine_idle.yaml``), shrinks the campaign where it
is long (Monte Carlo ``samples`` 1000 -> 2, ``duration`` 5 s -> 0.5 s: the
file otherwise as shipped) and runs ``belt-drive sweep`` on it with one
worker, as a user would. The fleet is built by ``examples/make_fleet.sh``
from the reference bags, and every recording must pass its comparison.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent

pytestmark = pytest.mark.slow


@pytest.fixture
def tree(tmp_path):
    shutil.copytree(ROOT / "examples", tmp_path / "examples",
                    ignore=shutil.ignore_patterns("fleet", "*.campaign"))
    shutil.copytree(ROOT / "bags", tmp_path / "bags")
    return tmp_path


def _env() -> dict:
    return {**os.environ, "PATH": f"{BIN}{os.pathsep}{os.environ.get('PATH', '')}"}


def _sweep(tree: Path, name: str, *extra: str) -> subprocess.CompletedProcess:
    return subprocess.run([str(BIN / "belt-drive"), "sweep", f"examples/{name}", "--workers", "1", "--quiet", *extra],
                          cwd=tree, env=_env(), capture_output=True, text=True, timeout=300)


def _shrink(path: Path, samples: int | None = None, duration: float = 0.5) -> dict:
    """Rewrite a campaign file with fewer samples and a shorter duration; return it as read."""
    data = yaml.safe_load(path.read_text(encoding="utf-8"))
    data.setdefault("set", {})["duration"] = duration
    if samples is not None:
        data["monte_carlo"]["samples"] = samples
    path.write_text(yaml.safe_dump(data, sort_keys=False), encoding="utf-8")
    return data


def test_tolerance_monte_carlo_example_runs(tree):
    data = _shrink(tree / "examples" / "paper_tolerances.yaml", samples=2)
    assert not set(data["grid"]) & set(data["monte_carlo"]["vary"])  # a key on the grid or drawn, not both
    proc = _sweep(tree, "paper_tolerances.yaml", "--csv", "--plots")  # (docs/campaigns.md's command: not run there)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    table = pd.read_parquet(tree / "examples" / "paper_tolerances.campaign" / "results.parquet")
    points = 1
    for values in data["grid"].values():
        points *= len(values)
    assert len(table) == points * len(data["profiles"]) * 2
    assert table["error"].fillna("").eq("").all(), table["error"].unique()
    assert (table["peak_belt_torque"] > 0).all() and table["params.c"].nunique() == len(table)  # c drawn per run
    assert (tree / "examples" / "paper_tolerances.campaign" / "results.csv").is_file()
    for chart in ("histograms.png", "metrics_vs_parameters.png"):
        assert (tree / "examples" / "paper_tolerances.campaign" / chart).read_bytes()[:4] == b"\x89PNG", chart


def test_grid_example_runs(tree):
    data = _shrink(tree / "examples" / "paper_grid.yaml")
    proc = _sweep(tree, "paper_grid.yaml")
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    table = pd.read_parquet(tree / "examples" / "paper_grid.campaign" / "results.parquet")
    assert len(table) == len(data["grid"]["params.k"]) * len(data["grid"]["params.F_0"])
    assert table["error"].fillna("").eq("").all(), table["error"].unique()
    # more pre-tension, more slack-span force (F_slack = F_0 - |Q|/2)
    by_f0 = table.groupby("params.F_0")["min_slack_force"].min()
    assert by_f0.is_monotonic_increasing and by_f0.iloc[-1] > by_f0.iloc[0]


def test_fleet_is_built_from_the_bags_and_passes(tree):
    proc = subprocess.run(["sh", "examples/make_fleet.sh"], cwd=tree, env=_env(), capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, proc.stderr
    recordings = sorted(p.name for p in (tree / "examples" / "fleet" / "recordings").glob("*.mcap"))
    assert recordings == sorted(p.name for p in (tree / "examples" / "fleet" / "golden").glob("*.mcap"))
    assert len(recordings) == 3
    proc = _sweep(tree, "fleet.yaml")
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    assert "fleet compare: 3 of 3 recordings pass" in proc.stdout
    table = pd.read_parquet(tree / "examples" / "fleet.campaign" / "results.parquet")
    assert table["compare_passed"].all()
    # a changed drive fails the comparison: the fleet checks something
    scene = tree / "bags" / "engine_idle.yaml"
    scene.write_text(scene.read_text(encoding="utf-8").replace("k: 300000.0", "k: 303000.0"), encoding="utf-8")
    proc = _sweep(tree, "fleet.yaml", "--out", "changed", "--force")
    assert proc.returncode == 1 and "fleet compare: 0 of 3 recordings pass" in proc.stdout, proc.stdout[-2000:]
