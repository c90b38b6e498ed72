"""Compare two recordings signal by signal inside a tolerance tube.

A *signal* is one scalar time series: ``drive_torque/data`` for a
``std_msgs/Float64`` topic, ``joint_states/position[wheel_3]`` for one joint of
a ``sensor_msgs/JointState`` topic, ``topic/field.path`` for numeric fields of
other types. File A is the run under test, file B the reference: B is
interpolated onto A's sample times.

For each signal, with :math:`b` the reference interpolated at A's sample times
inside the common time range,

.. math::  |a_i - b_i| \\le \\mathrm{atol} + \\mathrm{rtol}\\,|b_i| \\quad \\forall i

(the rule of :func:`numpy.isclose`), and both series must cover at least
``min_coverage`` of their samples inside the common range, so a run that
stopped early fails instead of passing on its shorter overlap.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import Dict, Iterable, List, Optional, Tuple

import numpy as np

from .errors import MsgToolsError
from .reader import FLOAT64, JOINT_STATE, TopicData, read_bag

__all__ = ["CompareReport", "SignalResult", "compare", "signals_of"]

TIME_BASES = ("auto", "absolute", "relative")


@dataclass
class SignalResult:
    """Outcome for one signal.

    Attributes
    ----------
    name : str
        ``topic/field[joint]`` (topic without the leading ``/``).
    passed : bool
        All compared samples inside the tube and coverage sufficient.
    n_compared : int
        Samples of A compared.
    worst_abs_error : float
        max |a - b| (``inf`` where exactly one of a, b is NaN).
    worst_rel_error : float
        max |a - b| / |b| (``inf`` if b = 0 and a != b).
    time_of_worst_s : float
        Time [s, from the start of A] of the sample with the largest
        |a - b| / (atol + rtol |b|), i.e. the worst violation of the tube.
    time_base : str
        ``"identical"``, ``"absolute"`` (interpolated in common time) or
        ``"relative"`` (each series from its own first sample).
    reason : str
        Why it failed (or a note); "" when it passed plainly.
    """

    name: str
    passed: bool
    n_compared: int = 0
    worst_abs_error: float = float("nan")
    worst_rel_error: float = float("nan")
    time_of_worst_s: float = float("nan")
    time_base: str = ""
    reason: str = ""
    tube_ratio: float = float("nan")


@dataclass
class CompareReport:
    """Result of :func:`compare`.

    Attributes
    ----------
    a_path, b_path : str
        Files compared (A under test, B reference).
    rtol, atol : float
        Tolerances used.
    signals : list of SignalResult
        One per signal, in topic order.
    skipped : list of (str, str)
        Topics without numeric signals and why (not failures).
    """

    a_path: str
    b_path: str
    rtol: float
    atol: float
    signals: List[SignalResult] = field(default_factory=list)
    skipped: List[Tuple[str, str]] = field(default_factory=list)

    @property
    def passed(self) -> bool:
        """True when there is at least one signal and every signal passed."""
        return bool(self.signals) and all(s.passed for s in self.signals)

    @property
    def failures(self) -> List[SignalResult]:
        """Signals that failed."""
        return [s for s in self.signals if not s.passed]

    @property
    def worst(self) -> Optional[SignalResult]:
        """The failing signal with the largest tube violation (else the closest call)."""
        pool = self.failures or self.signals
        if not pool:
            return None

        def key(s: SignalResult) -> float:
            if s.n_compared == 0:
                return float("inf")
            return s.tube_ratio if np.isfinite(s.tube_ratio) else float("inf")

        return max(pool, key=key)

    def table(self) -> str:
        """Return a fixed-width text table of all signals."""
        header = ("signal", "n", "worst abs err", "worst rel err", "at t [s]", "result")
        rows = [header]
        for s in self.signals:
            rows.append(
                (
                    s.name,
                    str(s.n_compared),
                    _fmt(s.worst_abs_error),
                    _fmt(s.worst_rel_error),
                    "-" if not np.isfinite(s.time_of_worst_s) else f"{s.time_of_worst_s:.6g}",
                    ("pass" if s.passed else "FAIL") + (f" ({s.reason})" if s.reason else ""),
                )
            )
        widths = [max(len(r[i]) for r in rows) for i in range(len(header) - 1)]
        lines = []
        for r in rows:
            cells = [r[i].ljust(widths[i]) if i == 0 else r[i].rjust(widths[i]) for i in range(len(widths))]
            lines.append("  ".join(cells + [r[-1]]))
        for topic, why in self.skipped:
            lines.append(f"(skipped {topic}: {why})")
        return "\n".join(lines)

    def verdict(self) -> str:
        """One line: PASS/FAIL with counts and the worst signal."""
        n, bad = len(self.signals), len(self.failures)
        if n == 0:
            return "FAIL: no signals to compare"
        if bad == 0:
            return f"PASS: {n} signals within atol={self.atol:g}, rtol={self.rtol:g}"
        worst = self.worst
        assert worst is not None
        where = (
            f" at t={worst.time_of_worst_s:.6g} s" if np.isfinite(worst.time_of_worst_s) else ""
        )
        detail = worst.reason or f"abs err {_fmt(worst.worst_abs_error)}{where}"
        return f"FAIL: {bad} of {n} signals outside tolerance; worst: {worst.name} ({detail})"


def _fmt(x: float) -> str:
    if x is None or (isinstance(x, float) and np.isnan(x)):
        return "-"
    if np.isinf(x):
        return "inf"
    return f"{x:.3e}"


def _short(topic: str) -> str:
    return topic.lstrip("/")


def signals_of(data: TopicData) -> Dict[str, Tuple[np.ndarray, np.ndarray]]:
    """Return ``{signal name: (time [ns] int64, values float64)}`` of one topic.

    Time is the header stamp for ``JointState`` and the log time otherwise.
    JointState columns that are NaN in every message (empty arrays) are left out.
    """
    base = _short(data.topic)
    out: Dict[str, Tuple[np.ndarray, np.ndarray]] = {}
    if data.type_name == FLOAT64:
        out[f"{base}/data"] = (data.log_time_ns, data.fields.get("data", np.zeros(0)))
    elif data.type_name == JOINT_STATE:
        t = data.fields["stamp_ns"]
        for fname in ("position", "velocity", "effort"):
            values = data.fields[fname]
            for j, joint in enumerate(data.names):
                column = values[:, j]
                if column.size and np.all(np.isnan(column)):
                    continue
                out[f"{base}/{fname}[{joint}]"] = (t, column)
    else:
        for key, values in data.fields.items():
            if values.ndim == 1:
                out[f"{base}/{key}"] = (data.log_time_ns, values)
            else:
                for k in range(values.shape[1]):
                    out[f"{base}/{key}[{k}]"] = (data.log_time_ns, values[:, k])
    return out


def _errors(a: np.ndarray, b: np.ndarray, rtol: float, atol: float) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return |a-b|, |a-b|/|b| and |a-b|/(atol+rtol|b|), NaN-aware."""
    both_nan = np.isnan(a) & np.isnan(b)
    one_nan = np.isnan(a) ^ np.isnan(b)
    with np.errstate(invalid="ignore"):
        err = np.abs(a - b)
    err = np.where(both_nan, 0.0, np.where(one_nan, np.inf, err))
    mag = np.abs(np.where(np.isnan(b), 0.0, b))
    rel = np.divide(err, mag, out=np.where(err > 0, np.inf, 0.0), where=mag > 0)
    tube = atol + rtol * mag
    ratio = np.divide(err, tube, out=np.where(err > 0, np.inf, 0.0), where=tube > 0)
    return err, rel, ratio


def _compare_signal(
    name: str,
    ta: np.ndarray,
    va: np.ndarray,
    tb: np.ndarray,
    vb: np.ndarray,
    rtol: float,
    atol: float,
    time_base: str,
    min_coverage: float,
    origin_ns: int,
) -> SignalResult:
    if va.size == 0 or vb.size == 0:
        which = "A" if va.size == 0 else "B"
        return SignalResult(name, False, reason=f"no samples in {which}")
    identical = ta.shape == tb.shape and np.array_equal(ta, tb)
    if identical:
        base = "identical"
    elif time_base == "relative":
        base = "relative"
    elif time_base == "absolute":
        base = "absolute"
    else:
        overlap = min(ta[-1], tb[-1]) >= max(ta[0], tb[0])
        base = "absolute" if overlap else "relative"
    if base == "relative":
        origin_ns = int(ta[0])
        ta = ta - ta[0]
        tb = tb - tb[0]
        if ta.shape == tb.shape and np.array_equal(ta, tb):
            base = "relative"
            identical = True

    if identical:
        b_on_a, mask = vb, np.ones(ta.shape, dtype=bool)
    else:
        lo, hi = max(ta[0], tb[0]), min(ta[-1], tb[-1])
        if hi < lo:
            return SignalResult(
                name, False, time_base=base,
                reason="no common time range (try --time-base relative)",
            )
        mask = (ta >= lo) & (ta <= hi)
        cover_a = mask.mean()
        cover_b = ((tb >= lo) & (tb <= hi)).mean()
        if cover_a < min_coverage or cover_b < min_coverage:
            return SignalResult(
                name, False, n_compared=int(mask.sum()), time_base=base,
                reason=(
                    f"common time range holds {100 * cover_a:.1f}% of A's and "
                    f"{100 * cover_b:.1f}% of B's samples"
                ),
            )
        t0 = lo
        xb = (tb - t0).astype(np.float64)
        xa = (ta[mask] - t0).astype(np.float64)
        order = np.argsort(xb, kind="stable")
        b_on_a = np.interp(xa, xb[order], vb[order])
    a = va[mask]
    err, rel, ratio = _errors(a, b_on_a, rtol, atol)
    worst = int(np.argmax(ratio))
    t_worst = (ta[mask][worst] - (0 if base == "relative" else origin_ns)) * 1e-9
    if not err.size or err.max() == 0:
        t_worst = float("nan")  # no error anywhere: no worst instant
    passed = bool(np.all(ratio <= 1.0))
    return SignalResult(
        name=name,
        passed=passed,
        n_compared=int(a.size),
        worst_abs_error=float(err.max()),
        worst_rel_error=float(rel.max()),
        time_of_worst_s=float(t_worst),
        time_base=base,
        tube_ratio=float(ratio.max()),
    )


def compare(
    a_path: "str | os.PathLike[str]",
    b_path: "str | os.PathLike[str]",
    topics: Optional[Iterable[str]] = None,
    rtol: float = 1e-6,
    atol: float = 1e-9,
    *,
    time_base: str = "auto",
    min_coverage: float = 0.99,
) -> CompareReport:
    """Compare the signals of bag A (under test) against bag B (reference).

    Parameters
    ----------
    a_path, b_path : path
        MCAP files.
    topics : iterable of str, optional
        Topics to compare; default all topics of both files. A topic missing
        from one file is a failure.
    rtol : float
        Relative tolerance [-].
    atol : float
        Absolute tolerance, in each signal's SI unit.
    time_base : {"auto", "absolute", "relative"}
        How to align times: identical time stamps are always used directly;
        ``absolute`` interpolates B onto A's times on the common clock;
        ``relative`` first shifts each series to start at 0; ``auto`` uses
        ``absolute`` if the series overlap in time, else ``relative``.
    min_coverage : float
        Fraction of each series' samples that must lie in the common time range.

    Returns
    -------
    CompareReport
    """
    if time_base not in TIME_BASES:
        raise ValueError(f"time_base must be one of {', '.join(TIME_BASES)}, got {time_base!r}")
    if not (rtol >= 0 and atol >= 0):
        raise ValueError(f"tolerances must be >= 0, got rtol={rtol}, atol={atol}")
    if not 0 < min_coverage <= 1:
        raise ValueError(f"min_coverage must be in (0, 1], got {min_coverage}")
    a_name, b_name = os.fspath(a_path), os.fspath(b_path)
    report = CompareReport(a_name, b_name, rtol, atol)

    def norm(t: str) -> str:
        return t if t.startswith("/") else "/" + t

    wanted_in = None if topics is None else list(dict.fromkeys(norm(t) for t in topics))
    bag_a = read_bag(a_path, wanted_in, missing_ok=True, keep_undecodable=True)
    bag_b = read_bag(b_path, wanted_in, missing_ok=True, keep_undecodable=True)
    data_a = {norm(t): d for t, d in bag_a.topics.items()}
    data_b = {norm(t): d for t, d in bag_b.topics.items()}
    if wanted_in is None:
        wanted = list(dict.fromkeys(list(data_a) + list(data_b)))
    else:
        wanted = wanted_in

    starts = [int(d.log_time_ns[0]) for d in data_a.values() if len(d)]
    origin_ns = min(starts) if starts else 0

    for topic in wanted:
        in_a, in_b = topic in data_a, topic in data_b
        short = _short(topic)
        if not (in_a and in_b):
            missing = "A" if not in_a else "B"
            path = a_name if not in_a else b_name
            report.signals.append(
                SignalResult(short, False, reason=f"topic {topic} missing in {missing} ({path})")
            )
            continue
        da, db = data_a[topic], data_b[topic]
        if da.decode_error or db.decode_error:
            which = "A" if da.decode_error else "B"
            report.signals.append(SignalResult(
                short, False, reason=f"cannot decode in {which}: {da.decode_error or db.decode_error}"))
            continue
        if da.type_name != db.type_name:
            report.signals.append(
                SignalResult(short, False, reason=f"type {da.type_name} in A but {db.type_name} in B")
            )
            continue
        sig_a, sig_b = signals_of(da), signals_of(db)
        if not sig_a and not sig_b:
            report.skipped.append((topic, f"{da.type_name} has no numeric signals"))
            continue
        for name in list(dict.fromkeys(list(sig_a) + list(sig_b))):
            if name not in sig_a or name not in sig_b:
                missing = "A" if name not in sig_a else "B"
                report.signals.append(SignalResult(name, False, reason=f"signal missing in {missing}"))
                continue
            (ta, va), (tb, vb) = sig_a[name], sig_b[name]
            report.signals.append(
                _compare_signal(
                    name, ta, va, tb, vb, rtol, atol, time_base, min_coverage, origin_ns
                )
            )
    if not report.signals and not report.skipped:
        raise MsgToolsError(f"nothing to compare: no topics in {a_name} or {b_name}")
    return report
