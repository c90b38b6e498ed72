"""A tolerance sweep's variants checked and tabulated column-wise (``Campaign.scenes_of``, ``run_batch``): the same
verdicts, parameters, errors and result table as the row-by-row path (``Campaign.scene_of`` per row)."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
import yaml

from belt_drive_ros.campaign import spec
from belt_drive_ros.campaign.execute import portable_of, run_batch
from belt_drive_ros.campaign.spec import Campaign
from belt_drive_ros.core.errors import ParameterError
from belt_drive_ros.core.params import FIELD_DOCS, PLAUSIBLE_MAX, BeltDriveParams, valid_parameter_rows


def _edges(name: str) -> list:
    """Values at and around every bound a field has (0, the plausible maximum, 2 pi, pi), and non-finite ones."""
    top = PLAUSIBLE_MAX[name]
    values = [0.0, -0.0, 5e-324, -5e-324, -1.0, 1.0, top, np.nextafter(top, math.inf), np.nextafter(top, 0.0),
              2.0 * math.pi, np.nextafter(2.0 * math.pi, 7.0), math.pi, np.nextafter(math.pi, 4.0), 1e300, -1e300,
              math.nan, math.inf, -math.inf]  # fmt: skip
    return [float(v) for v in values]


def _constructor_accepts(fields: dict) -> bool:
    try:
        BeltDriveParams(**fields).check_plausible()
    except ParameterError:
        return False
    return True


@pytest.mark.parametrize("name", list(FIELD_DOCS))
def test_the_column_check_gives_the_constructors_verdict_on_every_edge(name):
    base = BeltDriveParams().field_values()
    values = _edges(name)
    verdicts = valid_parameter_rows({name: np.array(values)}).tolist()
    expected = [_constructor_accepts(dict(base, **{name: v})) for v in values]
    assert verdicts == expected, list(zip(values, verdicts, expected))
    assert any(expected) and not all(expected)  # the edges fall on both sides


def _sweep(tmp_path, grid: dict, samples: int = 40):
    path = tmp_path / "c.yaml"
    path.write_text(yaml.safe_dump({
        "name": "c", "scene": "paper", "set": {"duration": 0.05}, "grid": grid,
        "monte_carlo": {"samples": samples, "seed": 3, "vary": {"params.c": {"normal": 0.5}, "params.I_3": {"uniform": [-0.1, 1.1]}}},
    }))  # fmt: skip
    return Campaign.load(path)


def test_scenes_of_equal_scene_of_row_by_row(tmp_path):
    """Good and bad rows mixed (a negative damping or inertia drawn, k = 0, F_0 = NaN, mu beyond its range): each
    good row the same parameters (Python floats, field for field), each bad row the same error type and text."""
    campaign = _sweep(tmp_path, {"params.k": [2.0e4, 0.0], "params.F_0": [400, math.nan], "params.mu": [0.3, 11.0]})
    table = campaign.variants()
    got = campaign.scenes_of(table)
    bad = 0
    for row, scene in zip(table.to_dict("records"), got):
        try:
            expected = campaign.scene_of(row)
        except Exception as exc:  # noqa: BLE001
            bad += 1
            assert type(scene) is type(exc) and str(scene) == str(exc)
            continue
        assert scene.params == expected.params and scene == expected
        assert all(type(v) is float for v in scene.params.__dict__.values())
        assert list(scene.params.__dict__) == list(expected.params.__dict__)
    assert 0 < bad < len(table)
    assert len(got) == len(table) == 320


def test_scenes_of_other_tables_go_row_by_row(tmp_path, monkeypatch):
    """A grid over a top-level key is not a tolerance sweep: the column path declines it, and the result is scene_of's."""
    campaign = _sweep(tmp_path, {"method": ["rk4", "nosuch"]}, samples=3)
    table = campaign.variants()
    assert campaign._parameter_scenes(table) is None
    got = campaign.scenes_of(table)
    kinds = [type(s).__name__ for s in got]
    assert kinds[3:] == ["SceneError"] * 3 and "Scene" in kinds[:3]
    for row, scene in zip(table.to_dict("records"), got):
        if not isinstance(scene, Exception):
            assert scene == campaign.scene_of(row)


def test_run_batch_column_wise_equals_row_by_row(tmp_path, monkeypatch):
    """The batch's table (ensembles, single runs of a small group, error rows) equals, column for column and type for
    type, the table of the same batch with every scene built by scene_of, and its metrics those of the rows."""
    campaign = _sweep(tmp_path, {"params.k": [2.0e4, -1.0], "params.F_0": [400.0, 120.0]}, samples=10)
    table = campaign.variants()
    portable = portable_of(campaign)
    columns = run_batch(portable, table)
    with monkeypatch.context() as m:
        m.setattr(Campaign, "_parameter_scenes", lambda self, frame: None)
        rows = run_batch(portable, table)
    by_list = run_batch(portable, table.to_dict("records"))
    for other in (rows, by_list):
        pd.testing.assert_frame_equal(columns.drop(columns="seconds"), other.drop(columns="seconds"))
    assert "ensemble" in set(columns["ran"]) and "none" in set(columns["ran"]) and (columns["error"] != "").sum() >= 20
    assert list(columns.columns[-10:-1]) == ["error", *spec.METRICS]


def test_a_base_scene_outside_the_ranges_gives_every_row_its_error(tmp_path):
    """A base field outside its plausible range fails every row, each with scene_of's error: the row's own (k < 0, I_3
    < 0 or c < 0, the constructor's) when it breaks one, else the base's F_0."""
    campaign = _sweep(tmp_path, {"params.k": [2.0e4, -1.0]}, samples=20)
    campaign.base = campaign.base.with_params(BeltDriveParams(**dict(campaign.base.params.field_values(), F_0=1e9)))
    table = campaign.variants()
    got = campaign._parameter_scenes(table)
    texts = [str(s) for s in got]
    assert all(isinstance(s, ParameterError) for s in got) and any("F_0: 1e+09 N is outside" in t for t in texts)
    assert any(t.startswith("k: must be > 0") for t in texts) and any(t.startswith(("c:", "I_3:")) for t in texts)
    for row, scene in zip(table.to_dict("records"), got):
        with pytest.raises(ParameterError) as info:
            campaign.scene_of(row)
        assert str(info.value) == str(scene)
