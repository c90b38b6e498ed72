"""One parameter rule table (core/params.py RULES, PLAUSIBLE_RULES): the scalar constructor (with check_plausible),
the column check (valid_parameter_rows) and the column-wise constructor (BeltDriveParams.replace_rows) read it, so
every rule, and a rule added to it, is enforced by all three with the same message."""

from __future__ import annotations

import ast
import math
from pathlib import Path

import numpy as np
import pytest

from belt_drive_ros.core import params as P
from belt_drive_ros.core.errors import ParameterError
from belt_drive_ros.core.params import PLAUSIBLE_RULES, RULES, BeltDriveParams, rule, valid_parameter_rows

TABLE = RULES + PLAUSIBLE_RULES


def _scalar(fields: dict):
    """The scalar path: the constructor, then check_plausible; the parameters or the error's text."""
    try:
        return BeltDriveParams(**fields).check_plausible()
    except ParameterError as exc:
        return str(exc)


def _first_broken(fields: dict, table=TABLE):
    """The text of the first rule of ``table`` a value of ``fields`` breaks (None: none), read off the table."""
    for r in table:
        if not r.holds(fields[r.field]):
            return str(r.error(fields[r.field]))
    return None


def _candidates(r) -> list:
    """Values on both sides of each finite end of ``r``, the non-finite ones and the field's default."""
    out = [math.nan, math.inf, -math.inf, getattr(BeltDriveParams(), r.field)]
    for end in (r.low, r.high):
        if math.isfinite(end):
            out += [end, math.nextafter(end, -math.inf), math.nextafter(end, math.inf)]
    return out


@pytest.mark.parametrize("index", range(len(TABLE)), ids=[f"{r.field}:{r.text[:24]}" for r in TABLE])
def test_every_rule_is_enforced_by_the_scalar_and_the_column_path_alike(index):
    r = TABLE[index]
    base = BeltDriveParams().field_values()
    values = _candidates(r)
    rows = [dict(base, **{r.field: v}) for v in values]
    scalar = [_scalar(row) for row in rows]
    expected = [_first_broken(row) for row in rows]
    assert [s if isinstance(s, str) else None for s in scalar] == expected
    verdicts = valid_parameter_rows({r.field: np.array(values)}).tolist()
    assert verdicts == [e is None for e in expected]
    built = BeltDriveParams().replace_rows({r.field: np.array(values)}, plausible=True)
    for s, b in zip(scalar, built):
        if isinstance(s, str):
            assert isinstance(b, ParameterError) and str(b) == s
        else:
            assert b == s and list(b.__dict__.items()) == list(s.__dict__.items())
    # the rule is the one that refuses some value, unless an earlier rule of its field is at least as strict
    earlier = [q for q in TABLE[:index] if q.field == r.field and q.low >= r.low and q.high <= r.high]
    assert earlier or any(e == str(r.error(v)) for e, v in zip(expected, values))
    assert expected[3] is None and sum(e is not None for e in expected) >= 3


def test_a_rule_added_to_the_table_is_enforced_by_both_paths(monkeypatch):
    stricter = rule("k", None, 1.0e6, "(]", "must be <= 1e6 N/m in this test, got {value!r}")
    assert BeltDriveParams(k=2.0e6).k == 2.0e6
    monkeypatch.setattr(P, "RULES", RULES + (stricter,))
    with pytest.raises(ParameterError, match=r"^k: must be <= 1e6 N/m in this test, got 2000000.0$"):
        BeltDriveParams(k=2.0e6)
    assert BeltDriveParams(k=1.0e6).k == 1.0e6
    assert valid_parameter_rows({"k": np.array([2.0e6, 1.0e6, np.nextafter(1.0e6, 2.0e6)])}).tolist() == [False, True, False]
    got = BeltDriveParams().replace_rows({"k": np.array([2.0e6, 5.0e5])})
    assert str(got[0]) == "k: must be <= 1e6 N/m in this test, got 2000000.0" and got[1] == BeltDriveParams(k=5.0e5)
    plausible = rule("c", None, 50.0, "()", "{value:g} N s/m is beyond this test's 50")
    monkeypatch.setattr(P, "PLAUSIBLE_RULES", PLAUSIBLE_RULES + (plausible,))
    with pytest.raises(ParameterError, match=r"^c: 50 N s/m is beyond this test's 50$"):
        BeltDriveParams(c=50.0).check_plausible()
    assert valid_parameter_rows({"c": np.array([50.0, 49.0])}).tolist() == [False, True]
    assert valid_parameter_rows({"c": np.array([50.0, 49.0])}, plausible=False).tolist() == [True, True]
    monkeypatch.undo()
    assert BeltDriveParams(k=2.0e6).k == 2.0e6 and valid_parameter_rows({"k": np.array([2.0e6])}).tolist() == [True]


def test_the_first_broken_rule_names_the_error_when_several_break():
    """The constructor's order: finiteness of every field first (in field order), then the bounds; a value that is not
    a number is reported where its finiteness would be."""
    with pytest.raises(ParameterError, match=r"^F_0: must be finite, got nan$"):
        BeltDriveParams(k=-1.0, F_0=math.nan)
    with pytest.raises(ParameterError, match=r"^I_3: must be finite"):
        BeltDriveParams(I_3=math.inf, k="stiff")
    with pytest.raises(ParameterError, match=r"^k: must be a number, got str"):
        BeltDriveParams(I_3=-1.0, k="stiff")
    row = {"k": np.array([-1.0]), "F_0": np.array([math.nan])}
    assert str(BeltDriveParams().replace_rows(row)[0]) == "F_0: must be finite, got nan"


def test_replace_rows_builds_only_what_the_rules_pass():
    base = BeltDriveParams()
    got = base.replace_rows({"k": np.array([3.0e4, 0.0, 2e10]), "mu": np.array([0.3, 0.3, 0.3])}, plausible=True)
    assert got[0] == base.replace(k=3.0e4, mu=0.3) and all(type(v) is float for v in got[0].__dict__.values())
    assert str(got[1]) == "k: must be > 0 N/m, got 0.0"
    assert str(got[2]) == "k: 2e+10 N/m is outside the plausible range [1, 1e+10] N/m"
    assert base.replace_rows({"k": np.array([2e10])})[0].k == 2e10  # (the constructor alone: no plausible range)
    implausible = BeltDriveParams(F_0=1e9)
    assert str(implausible.replace_rows({"k": np.array([3.0e4])}, plausible=True)[0]).startswith("F_0: 1e+09 N is outside")
    assert np.array(3).dtype.kind == "i" and base.replace_rows({"k": np.array([20000])})[0].k == 20000.0
    with pytest.raises(ParameterError, match=r"^spring: unknown parameter"):
        base.replace_rows({"spring": np.array([1.0])})
    for bad in (np.array(["1.0"]), np.array([True]), np.array([[1.0]]), np.array([1.0 + 0j])):
        with pytest.raises(ParameterError, match=r"^k: expected a column of numbers"):
            base.replace_rows({"k": bad})
    with pytest.raises(ParameterError, match=r"^mu: expected a column of numbers as long as the others"):
        base.replace_rows({"k": np.array([1.0, 2.0]), "mu": np.array([0.3])})


def test_campaign_imports_no_private_name():
    """campaign/ builds parameters through core/params.py's public rule table and constructors only."""
    folder = Path(__file__).resolve().parents[1] / "belt_drive_ros" / "campaign"
    for path in folder.glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom):
                private = [a.name for a in node.names if a.name.startswith("_")]
                assert not private, f"{path.name} imports {private} from {node.module}"
            if isinstance(node, ast.Attribute) and node.attr == "__new__":
                raise AssertionError(f"{path.name} calls __new__ (line {node.lineno})")
