"""Hostile variant values in a campaign: a variant outside the plausible ranges a scene file
is held to is that variant's error row, and the batch it shares with good variants still runs them."""

from __future__ import annotations

import math

import yaml

from belt_drive_ros.campaign.execute import portable_of, run_batch
from belt_drive_ros.campaign.spec import Campaign
from belt_drive_ros.cli import main


def test_variants_outside_the_plausible_ranges_are_refused_one_by_one(tmp_path, capsys):
    """Before: a grid of params.c = 1e300 / params.I_M = 1e300 (a scene file refuses both: 'outside the plausible
    range') ran the variants; the accuracy guard's eigenvalues of an overflowed matrix raised LinAlgError, which
    failed the whole batch ('batch failed' for the good variant too) and made ``sweep --check`` an internal error
    after three numpy warnings."""
    path = tmp_path / "c.yaml"
    path.write_text(yaml.safe_dump({"name": "c", "scene": "paper", "set": {"duration": 0.05},
                                    "grid": {"params.c": [1.0e300, 1.0], "params.I_M": [1.0e300, 0.01]}}))
    campaign = Campaign.load(path)
    rows = run_batch(portable_of(campaign), campaign.variants()).to_dict("records")
    errors = [r["error"] for r in rows]
    assert [e.split(":")[0] for e in errors] == ["ParameterError"] * 3 + [""], errors
    assert all("plausible range" in e for e in errors[:3]), errors
    assert rows[3]["peak_belt_torque"] > 0 and not math.isnan(rows[3]["final_speed"])
    assert main(["sweep", str(path), "--check", "--quiet"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("belt-drive: error: variant 0: ParameterError: ") and "plausible range" in err[0], err
