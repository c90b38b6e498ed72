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
stopped early fails instead of passing on its shorter overlap. Coverage also
means no holes: a series with two samples at the same time, or with a gap
longer than ``max_gap_periods`` times its median sample period, fails
(a lost or duplicated chunk, a stalled recorder).

A file that is not whole (cut off: its writer was killed, the last chunk
lost) fails the comparison, whatever its signals show: its last samples are
missing, and a tolerance tube cannot see what is not there (a golden file
cut after the last complete chunk lacked the last sample of six topics and
passed). A cut file that holds every sample the other, whole, file has (cut
after its data, in its summary or footer) fails too: it was not finished, and
nothing in it checks that what it holds is all it had. ``allow_incomplete=True``
compares what was read instead, with the missing samples named as a note.

Folders of recordings are compared pairwise by file name
(:func:`compare_folders`).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import Dict, Iterable, List, Optional, Tuple

import numpy as np

from .decode import FLOAT64, JOINT_STATE
from .errors import MsgToolsError
from .reader import TopicData, read_bag

__all__ = ["CompareReport", "FolderReport", "SignalResult", "compare", "compare_folders", "signals_of"]

TIME_BASES = ("auto", "absolute", "relative")
#: the type of /tf: skipped when only one file has it (see :func:`compare`)
TF_MESSAGE = "tf2_msgs/msg/TFMessage"


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
        ``"relative"`` (each file from its first stamp).
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
    incomplete: List[str] = field(default_factory=list)
    allow_incomplete: bool = False
    #: the time base of the comparison (one for the file pair): ``absolute`` or ``relative``
    time_base: str = ""

    @property
    def passed(self) -> bool:
        """True when there is at least one signal, every signal passed, and both files are whole
        (or ``allow_incomplete``)."""
        whole = not self.incomplete or self.allow_incomplete
        return bool(self.signals) and all(s.passed for s in self.signals) and whole

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
        lines = _aligned(rows, right=True)
        if self.time_base == "relative":
            lines.append("(time base: relative, each file from its first stamp)")
        for topic, why in self.skipped:
            lines.append(f"(skipped {topic}: {why})")
        for note in self.incomplete:
            lines.append(f"({'note' if self.allow_incomplete else 'FAIL'}: {note})")
        return "\n".join(lines)

    def verdict(self) -> str:
        """One line: PASS/FAIL with counts and the worst signal."""
        n, bad = len(self.signals), len(self.failures)
        if n == 0:
            return "FAIL: no signals to compare"
        if bad == 0 and self.incomplete and not self.allow_incomplete:
            return (f"FAIL: {self.incomplete[0]}" + (f" (and {len(self.incomplete) - 1} more)" if len(self.incomplete) > 1
                                                    else "") + "; --allow-incomplete compares what was read")
        if bad == 0:
            return (f"PASS: {n} signals within atol={self.atol:g}, rtol={self.rtol:g}"
                    + (" (of what was read: a file is incomplete)" if self.incomplete else ""))
        worst = self.worst
        assert worst is not None
        where = (
            f" at t={worst.time_of_worst_s:.6g} s" if np.isfinite(worst.time_of_worst_s) else ""
        )
        # (the time is that of the sample farthest outside its tube, not of the largest absolute error)
        detail = worst.reason or f"abs err {_fmt(worst.worst_abs_error)}; farthest outside its tube{where}"
        return f"FAIL: {bad} of {n} signals outside tolerance; worst: {worst.name} ({detail})"


def _aligned(rows: List[Tuple[str, ...]], right: bool) -> List[str]:
    """Fixed-width lines of ``rows``: the first column left-aligned, the middle ones right-aligned
    (``right``) or left-aligned, the last one as is."""
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]) - 1)]
    return ["  ".join([r[i].rjust(widths[i]) if right and i else r[i].ljust(widths[i])
                       for i in range(len(widths))] + [r[-1]]) for r in rows]


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
        if "stamp_ns" not in data.fields:  # a channel without a message: no signal (compare says "no samples")
            return out
        t = data.fields["stamp_ns"]
        for fname in ("position", "velocity", "effort"):
            values = data.fields[fname]
            for j, joint in enumerate(data.names):
                column = values[:, j]
                if column.size and np.all(np.isnan(column)):
                    continue
                out[f"{base}/{fname}[{joint}]"] = (t, column)
    else:
        sparse = getattr(data, "sparse", set()) or set()
        for key, values in data.fields.items():
            columns = [(f"{base}/{key}", values)] if values.ndim == 1 else [
                (f"{base}/{key}[{k}]", values[:, k]) for k in range(values.shape[1])]
            for name, column in columns:
                if key in sparse:  # the messages that have it (a frame of an alternating /tf)
                    keep = ~np.isnan(column)
                    out[name] = (data.log_time_ns[keep], column[keep])
                else:
                    out[name] = (data.log_time_ns, column)
    return out


def _errors(a: np.ndarray, b: np.ndarray, rtol: float, atol: float) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return |a-b|, |a-b|/|b| and |a-b|/(atol+rtol|b|), NaN-aware."""
    both_nan = np.isnan(a) & np.isnan(b)
    one_nan = np.isnan(a) ^ np.isnan(b)
    with np.errstate(invalid="ignore"):
        err = np.abs(a - b)
    # equal values agree, infinities of one sign included (inf - inf is NaN): as two NaNs do
    err = np.where(both_nan | (a == b), 0.0, np.where(one_nan | np.isnan(err), np.inf, err))
    mag = np.abs(np.where(np.isnan(b), 0.0, b))
    rel = np.divide(err, mag, out=np.where(err > 0, np.inf, 0.0), where=mag > 0)
    tube = atol + rtol * mag
    ratio = np.divide(err, tube, out=np.where(err > 0, np.inf, 0.0), where=tube > 0)
    return err, rel, ratio


def _holes(t: np.ndarray, max_gap_periods: float, origin_ns: int, duplicates: bool = True,
           other: np.ndarray | None = None) -> str:
    """Why the time series ``t`` [ns] has holes ("" if none): duplicate stamps (unless ``duplicates`` is False),
    or a gap longer than ``max_gap_periods`` median periods (0 disables the gap check). With ``other`` (the other
    file's series), a gap between two stamps the other has as neighbours too, or duplicates of a stamp the other
    has as often, is both files' (a /clock jump a recording and its re-simulation share): not a hole."""
    if t.size < 2:
        return ""
    d = np.diff(t)
    dup = np.flatnonzero(d == 0) if duplicates else np.empty(0, dtype=np.intp)
    if dup.size and other is not None:  # (duplicates the other has at the same stamps: pair in order)
        stamps, counts = np.unique(t[dup], return_counts=True)
        theirs = np.searchsorted(other, stamps, side="right") - np.searchsorted(other, stamps, side="left")
        shared = np.isin(t[dup], stamps[theirs >= counts + 1])
        dup = dup[~shared]
    if dup.size:
        return (f"{dup.size} duplicate time stamps (first at t={(int(t[dup[0]]) - origin_ns) * 1e-9:.6g} s)")
    if max_gap_periods > 0 and t.size >= 3:
        period = float(np.median(d))
        if period > 0:
            gaps = np.flatnonzero(d > max_gap_periods * period)
            if gaps.size and other is not None:  # a gap the other has between the same two stamps
                i = np.searchsorted(other, t[gaps])
                ok = (i + 1 < other.size) & (other[np.minimum(i, other.size - 1)] == t[gaps])
                ok &= other[np.minimum(i + 1, other.size - 1)] == t[gaps + 1]
                gaps = gaps[~ok]
            if gaps.size:
                worst = int(gaps[np.argmax(d[gaps])])
                return (f"a gap of {d[worst] * 1e-9:.6g} s ({d[worst] / period:.1f} periods) at "
                        f"t={(int(t[worst]) - origin_ns) * 1e-9:.6g} s")
    return ""


def _common(ta: np.ndarray, tb: np.ndarray) -> tuple:
    """``(lo, hi, mask, cover_a, cover_b)``: the common time range of the series ``ta``, ``tb`` [ns], which of A's
    samples lie in it, and the share of A's and of B's samples that do."""
    lo, hi = max(ta[0], tb[0]), min(ta[-1], tb[-1])
    mask = (ta >= lo) & (ta <= hi)
    return lo, hi, mask, mask.mean(), ((tb >= lo) & (tb <= hi)).mean()


def _file_time_base(pending: list, time_base: str, min_coverage: float) -> Tuple[str, Tuple[int, int] | None]:
    """``(time base, (A's start, B's start) [ns])`` for every signal of a file pair (``pending``: ``(name, ta, va, tb,
    vb)``). ``auto``: absolute where the files' common time range (over all their signals) covers ``min_coverage`` of
    each file's span, else relative, each file from its first stamp. One base for all: chosen signal by signal, a
    topic logged 60 ms late in one file fell below the coverage alone and was compared from its own start (passed)."""
    series = [(x[1], x[3]) for x in pending if x[1].size and x[3].size]
    if not series:
        return ("relative" if time_base == "relative" else "absolute"), None
    a0, a1 = min(int(ta[0]) for ta, _ in series), max(int(ta[-1]) for ta, _ in series)
    b0, b1 = min(int(tb[0]) for _, tb in series), max(int(tb[-1]) for _, tb in series)
    if time_base != "auto":
        return time_base, (a0, b0)
    overlap = min(a1, b1) - max(a0, b0)
    covers = overlap >= 0 and all(span == 0 or overlap >= min_coverage * span for span in (a1 - a0, b1 - b0))
    return ("absolute" if covers else "relative"), (a0, b0)


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
    max_gap_periods: float = 5.0,
    starts: Tuple[int, int] | None = None,
) -> SignalResult:
    """One signal of A against B's. ``time_base``: ``absolute`` or ``relative`` (:func:`_file_time_base` decides
    ``auto`` once per file pair); ``starts``: the files' first stamps [ns] a relative comparison counts from (default each
    series' own first sample), so a topic logged late in one file is late from its file's start."""
    if va.size == 0 or vb.size == 0:
        which = "A" if va.size == 0 else "B"
        return SignalResult(name, False, reason=f"no samples in {which}")
    identical = ta.shape == tb.shape and np.array_equal(ta, tb)
    for which, t in (("A", ta), ("B", tb)):
        # a gap or duplicate stamps both series have at the same stamps are no sample missing from one of them, nor
        # an ambiguous pairing (a /clock jump the recording and its re-simulation share; a raw input two messages of
        # which arrived within one /clock period, logged at one time, passed through): the samples pair in order.
        # Only a gap or duplicates of one series are holes
        hole = _holes(t, 0.0 if identical else max_gap_periods, int(ta[0]) if which == "A" else int(tb[0]),
                      duplicates=not identical, other=tb if which == "A" else ta)
        if hole:
            return SignalResult(name, False, time_base="", reason=f"{hole} in {which}")
    base = "identical" if identical else time_base  # (absolute or relative: :func:`_file_time_base` decided)
    if base == "relative":
        a0, b0 = starts if starts is not None else (int(ta[0]), int(tb[0]))
        origin_ns = a0
        ta = ta - a0
        tb = tb - b0
        if ta.shape == tb.shape and np.array_equal(ta, tb):
            base = "relative"
            identical = True

    if identical:
        b_on_a, mask = vb, np.ones(ta.shape, dtype=bool)
    else:
        lo, hi, mask, cover_a, cover_b = _common(ta, tb)
        if hi < lo:
            return SignalResult(
                name, False, time_base=base,
                reason="no common time range (try --time-base relative)",
            )
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
        # a stamp both files have pairs exactly, each occurrence with the other's in order (duplicates both files
        # have: interpolation took one of B's values for all of A's)
        sb, vs, sa = tb[order], vb[order], ta[mask]
        if sa.size and bool(np.all(sa[1:] >= sa[:-1])):  # (A's stamps in order: their occurrences are counted)
            left, right = np.searchsorted(sb, sa, "left"), np.searchsorted(sb, sa, "right")
            occurrence = np.arange(sa.size) - np.searchsorted(sa, sa, "left")
            exact = left + occurrence < right
            b_on_a[exact] = vs[(left + occurrence)[exact]]
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
    max_gap_periods: float = 5.0,
    allow_incomplete: bool = False,
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
        How to align times, one base for the file pair: identical time stamps
        are always used directly; ``absolute`` interpolates B onto A's times on
        the common clock; ``relative`` first shifts each file to start at 0
        (its first stamp over the signals compared: a topic logged late in one
        file stays late); ``auto`` uses ``absolute`` if the files' common time
        range covers ``min_coverage`` of each file's span, else ``relative``
        (two runs of a scene started seconds apart on the wall clock overlap
        partly: they compare from their starts).
    min_coverage : float
        Fraction of each series' samples that must lie in the common time range.
    max_gap_periods : float
        A series fails when two samples are further apart than this many
        median sample periods (0: no gap check); duplicate stamps fail. A gap or duplicates both
        series have at the same stamps are neither (their samples pair in order).
    allow_incomplete : bool
        Compare a file that was cut off (its last chunk lost) as far as it
        was read. Default: such a file fails the comparison, its missing
        samples named per topic (``report.incomplete``).

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
    if not max_gap_periods >= 0:
        raise ValueError(f"max_gap_periods must be >= 0 (0: no gap check), got {max_gap_periods}")
    a_name, b_name = os.fspath(a_path), os.fspath(b_path)
    report = CompareReport(a_name, b_name, rtol, atol, allow_incomplete=allow_incomplete)

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

    report.incomplete = _incomplete(bag_a, data_a, "A", bag_b, data_b) + _incomplete(bag_b, data_b, "B", bag_a, data_a)
    starts = [int(d.log_time_ns[0]) for d in data_a.values() if len(d)]
    origin_ns = min(starts) if starts else 0

    for topic in wanted:
        in_a, in_b = topic in data_a, topic in data_b
        short = _short(topic)
        if not in_a and not in_b:  # asked for by --topics
            report.signals.append(SignalResult(short, False, reason=f"topic {topic} in neither file"))
            continue
        if not (in_a and in_b):
            missing = "A" if not in_a else "B"
            present = data_a[topic] if in_a else data_b[topic]
            if wanted_in is None and not present.decode_error and not signals_of(present):
                # e.g. /robot_description in a new recording, not in an older golden: nothing to compare
                report.skipped.append((topic, f"{present.type_name} has no numeric signals (only in "
                                              f"{'A' if in_a else 'B'})"))
                continue
            if wanted_in is None and present.type_name == TF_MESSAGE:
                # the transforms joint_states' angles give (compared where both files have them): a golden written
                # without /tf is no sample missing
                report.skipped.append((topic, f"{TF_MESSAGE} only in {'A' if in_a else 'B'} (the transforms "
                                              "of joint_states, compared where both files have them)"))
                continue
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
        if not len(da) and not len(db):  # (a channel declared in both, never written: nothing differs)
            report.skipped.append((topic, "no messages in either file"))
            continue
        if not len(da) or not len(db):
            report.signals.append(SignalResult(short, False, reason=f"no samples in {'A' if not len(da) else 'B'}"))
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
            report.signals.append((name, *sig_a[name], *sig_b[name]))  # (compared below, on the files' time base)
    base, starts = _file_time_base([x for x in report.signals if isinstance(x, tuple)], time_base, min_coverage)
    report.time_base = base
    report.signals = [
        _compare_signal(x[0], x[1], x[2], x[3], x[4], rtol, atol, base, min_coverage, origin_ns, max_gap_periods,
                        starts) if isinstance(x, tuple) else x
        for x in report.signals
    ]
    if not report.signals and not report.skipped:
        raise MsgToolsError(f"nothing to compare: no topics in {a_name} or {b_name}")
    return report


def _incomplete(bag, data: Dict[str, TopicData], side: str, other, other_data: Dict[str, TopicData]) -> List[str]:
    """One line when ``bag`` (file ``side``) was cut off: where it stopped and, against the other
    file (when that one is whole), the samples it lacks per topic (or that it holds every one of them
    but was not finished). [] for a whole file."""
    if bag.complete:
        return []
    lost = []
    other_side = "B" if side == "A" else "A"
    if other.complete:
        for topic, o in other_data.items():
            d = data.get(topic)
            if d is None or len(o) > len(d):
                lost.append(f"{topic} {len(o) - (0 if d is None else len(d))}")
        if not lost:
            return [f"{side} ({bag.path}) is incomplete ({bag.stop_reason or 'cut off'}): it holds every sample "
                    f"{other_side} has, but it was not finished (nothing in it says that is all it had)"]
    what = (f"lacks the last samples of {len(lost)} topic{'s' if len(lost) != 1 else ''} against "
            f"{other_side}: {', '.join(lost)}" if lost else "its last samples are missing")
    return [f"{side} ({bag.path}) is incomplete ({bag.stop_reason or 'cut off'}): {what}"]


# --------------------------------------------------------------------------
# folders of recordings
# --------------------------------------------------------------------------
def is_bag_folder(path: "str | os.PathLike[str]") -> bool:
    """True for a rosbag2 bag folder (``metadata.yaml``, or files ``NAME_k.mcap``), False
    for a folder of separate recordings."""
    path = os.fspath(path)
    if not os.path.isdir(path):
        return False
    if os.path.isfile(os.path.join(path, "metadata.yaml")):
        return True
    name = os.path.basename(os.path.normpath(path))
    mcaps = [f for f in os.listdir(path) if f.endswith(".mcap")]
    return bool(mcaps) and all(f.startswith(name + "_") and f[len(name) + 1:-5].isdigit() for f in mcaps)


def recordings_in(folder: "str | os.PathLike[str]") -> Dict[str, str]:
    """The recordings in ``folder`` (recursively) by path relative to it: ``.mcap`` files
    and rosbag2 bag folders (not descended into)."""
    root = os.fspath(folder)
    out: Dict[str, str] = {}
    for dirpath, dirnames, filenames in os.walk(root):
        keep = []
        for d in sorted(dirnames):
            full = os.path.join(dirpath, d)
            if is_bag_folder(full):
                out[os.path.relpath(full, root)] = full
            else:
                keep.append(d)
        dirnames[:] = keep
        for f in sorted(filenames):
            if f.lower().endswith(".mcap"):  # (any case: run.MCAP is MCAP, as everywhere else)
                full = os.path.join(dirpath, f)
                out[os.path.relpath(full, root)] = full
    return dict(sorted(out.items()))


@dataclass
class FolderReport:
    """Result of :func:`compare_folders`: one row per recording name.

    Attributes
    ----------
    a_dir, b_dir : str
        Folders (A under test, B reference).
    rows : list of (str, CompareReport or None, str)
        Name, its report (None when it could not be compared) and the reason
        it could not (missing on one side, unreadable, damaged).
    """

    a_dir: str
    b_dir: str
    rows: List[Tuple[str, Optional[CompareReport], str]] = field(default_factory=list)

    @property
    def failed(self) -> List[str]:
        return [name for name, report, _ in self.rows if report is None or not report.passed]

    @property
    def passed(self) -> bool:
        return bool(self.rows) and not self.failed

    def table(self) -> str:
        header = ("recording", "signals", "failed", "worst", "result")
        rows = [header]
        for name, report, why in self.rows:
            if report is None:
                rows.append((name, "-", "-", "-", f"FAIL ({why})"))
                continue
            worst = report.worst
            detail = "-" if worst is None else (worst.name if worst.passed else
                                                f"{worst.name}: {worst.reason or _fmt(worst.worst_abs_error)}")
            if report.incomplete and not report.allow_incomplete and not report.failures:
                detail = report.incomplete[0].split(" (", 1)[0] + " incomplete"
            rows.append((name, str(len(report.signals)), str(len(report.failures)), detail,
                         "pass" if report.passed else "FAIL"))
        return "\n".join(_aligned(rows, right=False))

    def verdict(self) -> str:
        n, bad = len(self.rows), len(self.failed)
        if n == 0:
            return "FAIL: no recordings to compare"
        if bad == 0:
            return f"PASS: {n} recordings"
        return f"FAIL: {bad} of {n} recordings; first: {self.failed[0]}"


def compare_folders(a_dir: "str | os.PathLike[str]", b_dir: "str | os.PathLike[str]",
                    **options) -> FolderReport:
    """Compare the recordings of folder A (under test) with those of B (reference), pairwise
    by relative name, with :func:`compare` and ``options``. A recording on one side only, or
    one that cannot be read, is a failed row, not an error."""
    from .errors import MsgToolsError as _Err

    a, b = recordings_in(a_dir), recordings_in(b_dir)
    report = FolderReport(os.fspath(a_dir), os.fspath(b_dir))
    for name in sorted(set(a) | set(b)):
        if name not in a or name not in b:
            report.rows.append((name, None, f"missing in {'A' if name not in a else 'B'}"))
            continue
        try:
            report.rows.append((name, compare(a[name], b[name], **options), ""))
        except (_Err, OSError, ValueError) as exc:
            report.rows.append((name, None, " ".join(str(exc).split())))
    return report
