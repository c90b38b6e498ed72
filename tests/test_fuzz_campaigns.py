"""Fuzzed campaign files and bag folders (issue 24): every mutant is a clean error or a valid result; none crashes,
hangs, or is taken silently wrong.

The generators (:mod:`belt_drive_ros.benchmarks.hostile_campaign`) and runners are the ones
``belt-drive bench hostile --only campaign bagdir`` tabulates: campaign mutants go through the real command line,
``belt-drive sweep FILE --check`` (validation, up-front limits, the variant table and up to 8 variants run
in-process, their rows written as a Parquet part; no cluster), bag-folder mutants through ``msg-tools info``,
``export`` and ``compare``. Outcomes as in :mod:`belt_drive_ros.benchmarks.hostile`: a **crash** is a
traceback, an "internal error" or more than one error line; a **hang** an input past 20 s; **silent wrong**
exit 0 for an input that must be refused, a variant count other than the file states, or an export that
differs from the intact folder without a warning.
"""

from __future__ import annotations

import collections

import pytest

from belt_drive_ros.benchmarks import hostile
from belt_drive_ros.benchmarks.hostile import run_bag_folders, run_campaign_files
from belt_drive_ros.benchmarks.hostile_campaign import campaign_mutants


def _table(run, tmp_path) -> hostile.Table:
    table = hostile.Table()
    run(table, tmp_path, False)
    print(table.text())
    return table


def _assert_clean(table: hostile.Table) -> collections.Counter:
    (row,) = table.counts.values()
    bad = [d for d in table.details if d.split(": ")[1] in ("crash", "hang", "silent wrong")]
    assert row["crash"] == row["hang"] == row["silent wrong"] == 0, "\n".join(bad[:20]) + "\n" + table.text()
    return row


def test_every_campaign_mutant_is_a_clean_error_or_valid(tmp_path):
    row = _assert_clean(_table(run_campaign_files, tmp_path))
    mutants = list(campaign_mutants())
    assert row["tried"] == len(mutants) + 6 + 8 > 250
    must_fail = sum(1 for m in mutants if m[1])
    assert row["clean error"] >= must_fail + 6 + 8  # every must-fail mutant, special file and bad option refused
    # every valid mutant ran (those of "variant rows" are valid files whose variants fail: exit 1, a row each)
    assert row["ok"] >= sum(1 for m in mutants if not m[1] and m[4] is not None and m[0] != "variant rows") > 20


def test_every_bag_folder_mutant_is_a_clean_error_or_valid(tmp_path):
    row = _assert_clean(_table(run_bag_folders, tmp_path))
    assert row["tried"] > 150 and row["clean error"] > 100 and row["ok"] > 10


@pytest.mark.parametrize("label", ["samples=2.7", "vary {'uniform': [0.9, 1.1], 'absolute': 'false'}",
                                   "grid and vary: params.k", "billion laughs"])
def test_named_mutants_are_refused_in_one_line(tmp_path, label, capsys):
    from belt_drive_ros.cli import main

    data = next(m[3] for m in campaign_mutants() if m[2] == label)
    path = tmp_path / "campaign.yaml"
    path.write_bytes(data)
    assert main(["sweep", str(path), "--check"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("belt-drive: error: ")
