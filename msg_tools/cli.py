"""``msg-tools``: inspect, export, plot and compare ROS 2 MCAP recordings without ROS.

Exit status: 0 success (``compare``: all signals pass), 1 ``compare`` found
signals outside tolerance or a file incomplete, or ``info`` found the file damaged or
incomplete (data lost), 2 usage or
input/output error (``export``/``plot``/``compare`` refuse a damaged file). Errors are one line
on stderr, ``msg-tools: error: ...``; set ``MSG_TOOLS_DEBUG=1`` for tracebacks.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import math
import os
import sys
import warnings
from typing import IO, Any, Dict, List, Optional, Sequence, Tuple

import numpy as np

from belt_drive_ros.io.inputs import input_replaced

from .decode import FLOAT64, JOINT_STATE
from .errors import MsgToolsError, RecoveredBagWarning
from .files import new_part, output_mode, settle_parts
from .reader import TopicData, read_bag, summary
from .results import tick_gaps
from .units import RAD_PER_S_TO_RPM, UNITS_METADATA, is_shaft_speed, label, unit_for

PROG = "msg-tools"

EPILOG = """\
examples:
  msg-tools info run.mcap
  msg-tools export run.mcap --topic /joint_states --out joint_states.csv
  msg-tools plot run.mcap --topics /drive_torque /joint_states --out run.png
  msg-tools compare fresh.mcap bags/engine_idle_golden.mcap --rtol 1e-6 --atol 1e-9
  msg-tools compare new_runs/ golden_runs/

exit status: 0 ok / compare passed, 1 compare failed or info found damage or an incomplete file
(data lost), 2 usage or I/O error (a damaged file: export/plot/compare refuse it)
"""


class _UsageError(Exception):
    pass


class _Formatter(argparse.HelpFormatter):
    """Wrap one-paragraph descriptions; keep multi-line epilogs (examples) as written."""

    def _fill_text(self, text: str, width: int, indent: str) -> str:
        if "\n" in text:
            return "".join(indent + line for line in text.splitlines(keepends=True))
        return super()._fill_text(text, width, indent)


class _Parser(argparse.ArgumentParser):
    """ArgumentParser whose errors are one line and exit with status 2."""

    def error(self, message: str) -> None:  # type: ignore[override]
        raise _UsageError(f"{message} (see '{self.prog} --help')")


def _ns_to_s_text(ns: int) -> str:
    """Exact decimal seconds of an integer nanosecond value."""
    sign = "-" if ns < 0 else ""
    whole, frac = divmod(abs(int(ns)), 1_000_000_000)
    return f"{sign}{whole}.{frac:09d}"


def _num(x: float) -> str:
    return "nan" if math.isnan(x) else repr(float(x))


# ---------------------------------------------------------------------- info
def _date(ns: int) -> str:
    """``Nov 23 2026 10:00:00.123456789 (1795...)`` in UTC, as ``ros2 bag info`` lays it out."""
    import datetime

    sec, frac = divmod(int(ns), 1_000_000_000)
    when = datetime.datetime.fromtimestamp(sec, tz=datetime.timezone.utc)
    return f"{when:%b %d %Y %H:%M:%S}.{frac:09d} UTC ({_ns_to_s_text(ns)})"


def _size(n: int) -> str:
    for unit in ("B", "KiB", "MiB", "GiB"):
        if n < 1024 or unit == "GiB":
            return f"{n:.1f} {unit}" if unit != "B" else f"{n} B"
        n /= 1024.0
    return f"{n} B"


def cmd_info(args: argparse.Namespace, out: IO[str]) -> int:
    from .bagdir import bag_files

    files = bag_files(args.bag)
    status = 0
    summaries = {}
    for k, path in enumerate(files):
        if k:
            out.write("\n")
        file_status, summaries[path] = _info_one(path, args, out)
        status = max(status, file_status)
    if len(files) > 1 or os.path.isdir(args.bag):
        from .bagdir import folder_damage

        damage = folder_damage(args.bag, summaries=summaries)
        out.write(f"\nBag folder:        {args.bag} ({len(files)} files)\n")
        if damage:
            _write_damage(out, damage)
            out.write(f"Status:            DAMAGED ({_problems(damage)})\n")
            sys.stderr.write(f"{PROG}: warning: {args.bag} is damaged: {damage[0]}{_more(damage)}\n")
            status = 1
        else:
            out.write("Status:            complete (every file as metadata.yaml lists it)\n"
                      if os.path.isfile(os.path.join(args.bag, "metadata.yaml")) else
                      "Status:            no metadata.yaml (a recorder that was killed); files read as found\n")
    return status


def _problems(damage: List[str]) -> str:
    return f"{len(damage)} problem{'s' if len(damage) != 1 else ''}"


def _more(damage: List[str]) -> str:
    return f" (and {len(damage) - 1} more problems)" if len(damage) > 1 else ""


def _write_damage(out: IO[str], damage: List[str]) -> None:
    """One line per problem."""
    for i, problem in enumerate(damage):
        out.write(f"{'Damage:' if i == 0 else '':<19}{' '.join(problem.split())}\n")


def _info_one(path: str, args: argparse.Namespace, out: IO[str]) -> Tuple[int, Any]:
    from belt_drive_ros.io.inputs import InputError, parse_yaml

    s = summary(path, verify=not args.summary_only)
    w = out.write
    bag_meta = s.metadata_dict("rosbag2").get("serialized_metadata", "")
    try:  # bounded: the file's YAML may be hostile (aliases, nesting)
        data = parse_yaml(bag_meta, "rosbag2 metadata") if bag_meta else None
        distro = data.get("ros_distro", "") if isinstance(data, dict) else ""
    except InputError:
        distro = ""
    distro = distro if isinstance(distro, str) else ""
    w(f"Files:             {s.path}\n")
    w(f"Bag size:          {_size(s.size_bytes)}\n")
    w("Storage id:        mcap\n")
    w(f"ROS Distro:        {distro or '-'}\n")
    w(f"Duration:          {_ns_to_s_text(int(round(s.duration_s * 1e9)))}s\n")
    if s.start_ns is not None:
        w(f"Start:             {_date(s.start_ns)}\n")
        w(f"End:               {_date(s.end_ns)}\n")
    w(f"Messages:          {s.message_count}\n")
    width = max((len(t.topic) for t in s.topics), default=0)
    for i, t in enumerate(s.topics):
        lead = "Topic information: " if i == 0 else " " * 19
        w(f"{lead}Topic: {t.topic.ljust(width)} | Type: {t.type_name} | Count: {t.message_count} | "
          f"Serialization Format: {t.message_encoding} | Rate: {t.frequency_hz:.1f} Hz\n")
    if not s.topics:
        w("Topic information: \n")
    w(f"Profile:           {s.profile or '-'}\n")
    w(f"Library:           {s.library or '-'}\n")
    comp = ", ".join(c or "none" for c in s.compression) or "-"
    w(f"Chunks:            {s.chunk_count} ({comp})\n")
    status = 0
    if s.damage:
        _write_damage(out, s.damage)
        w(f"Status:            DAMAGED ({_problems(s.damage)}; counts above are what the data holds)\n")
        sys.stderr.write(f"{PROG}: warning: {s.path} is damaged: {s.damage[0]}{_more(s.damage)}\n")
        status = 1
    elif not s.complete:  # data lost at the end (the writer was killed): exit 1, as for damage
        w(f"Status:            INCOMPLETE, {s.stop_reason}; {s.message_count} messages recovered\n")
        status = 1
    elif s.recovered:
        w(f"Status:            RECOVERED, {s.recovered}; all {s.message_count} messages the summary counts read\n")
    elif s.from_summary:
        w("Status:            complete (summary section only; the data was not checked)\n")
    elif s.verified:
        w("Status:            complete (data checked against the summary section)\n")
    else:
        w("Status:            complete (read from the data; no summary section to check it against)\n")
    _write_tick_gaps(out, s)
    if args.qos:
        for t in s.topics:
            w(f"offered_qos_profiles of {t.topic}:\n")
            for line in (t.offered_qos_profiles or "(none)").splitlines():
                w(f"    {line}\n")
    w("Metadata:\n" if s.metadata else "Metadata:          none\n")
    for name, values in s.metadata:
        w(f"  {name}:\n")
        for key, value in values.items():
            text = value.replace("\n", "\\n")
            if len(text) > 70 and not args.full:
                text = text[:67] + "..."
            w(f"    {key}: {text}\n")
    return status, s


#: ``info`` lists at most this many tick gaps one by one (then a count)
GAPS_LISTED = 20


def _write_tick_gaps(out: IO[str], s: Any) -> None:
    """The gaps in a node's ticks it recorded (``tick_gap`` metadata records): a count, then one line each."""
    gaps = tick_gaps(s.metadata)
    if not gaps:
        return
    missed = sum(int(g.get("ticks_missed", 0) or 0) for g in gaps)
    out.write(f"Tick gaps:         {len(gaps)} recorded by the node, {missed} ticks never published\n")
    for g in gaps[:GAPS_LISTED]:
        try:
            span = f"{_ns_to_s_text(int(g['start_ns']))} s to {_ns_to_s_text(int(g['end_ns']))} s"
        except (KeyError, ValueError):
            span = "?"
        out.write(f"{'':19}{g.get('ticks_missed', '?')} missed, {span} ({g.get('time_base', '?')}): "
                  f"{' '.join(str(g.get('cause', '')).split())}\n")
    if len(gaps) > GAPS_LISTED:
        out.write(f"{'':19}... and {len(gaps) - GAPS_LISTED} more (tick_gap records below)\n")


# -------------------------------------------------------------------- columns
def _columns(data: TopicData, units: Dict[str, str]) -> List[Tuple[str, np.ndarray, str]]:
    """Return (column name, values (N,), unit) of a topic's numeric fields."""
    short = data.topic.rsplit("/", 1)[-1] or data.topic
    cols: List[Tuple[str, np.ndarray, str]] = []
    if data.decode_error:
        return cols
    if data.type_name == FLOAT64:
        cols.append((short, data.fields["data"], unit_for(data.topic, "data", units)))
    elif data.type_name == JOINT_STATE:
        for fname in ("position", "velocity", "effort"):
            values = data.fields.get(fname)
            if values is None:  # a channel without a message: nothing decoded, no column
                continue
            unit = unit_for(data.topic, fname, units)
            for j, joint in enumerate(data.names):
                if values.shape[0] and np.all(np.isnan(values[:, j])):
                    continue
                cols.append((f"{fname}[{joint}]", values[:, j], unit))
    else:
        for key, values in data.fields.items():
            unit = unit_for(data.topic, key, units)
            if values.ndim == 1:
                cols.append((key, values, unit))
            else:
                for k in range(values.shape[1]):
                    cols.append((f"{key}[{k}]", values[:, k], unit))
    return cols


# -------------------------------------------------------------------- export
def _check_out_dir(path: Optional[str], force: bool = False, suffix: str = "", bag: Optional[str] = None) -> None:
    """Refuse ``--out`` up front: a missing folder, an existing path without ``--force``, anything
    but a regular file (a device such as /dev/full, a FIFO, a folder), or the ``bag`` it is made from (--force or
    not: the bag would be lost); ``suffix``: the extension it must have."""
    if path is None:
        return
    if not path:
        raise MsgToolsError("--out: an empty path; give a file name")
    if bag is not None and input_replaced(path, [bag]) is not None:
        raise MsgToolsError(f"cannot write {path}: it is the bag {bag} being read; write elsewhere")
    folder = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(folder):
        raise MsgToolsError(f"cannot write {path}: directory {folder} does not exist")
    if suffix and not path.lower().endswith(suffix):
        raise MsgToolsError(f"cannot write {path}: the output must be a {suffix} file")
    if os.path.lexists(path):
        if not os.path.isfile(path) or os.path.islink(path):
            raise MsgToolsError(f"cannot write {path}: not a regular file; outputs are written to regular files only")
        if not force:
            raise MsgToolsError(f"{path} exists; pass --force to overwrite it")
    try:  # the temporary file the write will make: a folder of /proc, read-only or full is refused now
        fd, probe = new_part(path)
    except OSError as exc:
        raise MsgToolsError(f"cannot write {path}: cannot write into folder {folder}: {exc.strerror or exc}") from None
    os.close(fd)
    with contextlib.suppress(FileNotFoundError):
        os.unlink(probe)


@contextlib.contextmanager
def _atomic(path: str, force: bool, mode: str):
    """A file in ``path``'s folder that is renamed onto ``path`` only when the block succeeds:
    a failed write (disk full) leaves neither a partial file nor the temporary one."""
    _check_out_dir(path, force)
    removed = settle_parts(path)  # what a run killed while writing it left
    if removed:
        sys.stderr.write(f"{PROG}: warning: {path}: removed {len(removed)} unfinished temporary file(s) of a run "
                         f"killed while writing it ({', '.join(removed)})\n")
    fd, name = new_part(path)
    lock = os.dup(fd)  # the temporary file stays locked past its close, up to the rename
    done = False
    try:
        os.fchmod(fd, output_mode(path))  # as open() would leave it, not mkstemp's 0o600
        with (os.fdopen(fd, mode, newline="", encoding="utf-8") if "b" not in mode else os.fdopen(fd, mode)) as f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        if not force and os.path.lexists(path):
            raise MsgToolsError(f"{path} appeared while writing; pass --force to overwrite it")
        os.replace(name, path)
        done = True
    except OSError as exc:
        raise MsgToolsError(f"cannot write {path}: {exc.strerror or exc}; nothing written") from None
    finally:
        if not done:
            with contextlib.suppress(OSError):
                os.unlink(name)
        os.close(lock)


def cmd_export(args: argparse.Namespace, out: IO[str]) -> int:
    _check_out_dir(args.out, args.force, bag=args.bag)
    bag = read_bag(args.bag, [args.topic])
    data = next(iter(bag.topics.values()))
    units = bag.metadata_dict(UNITS_METADATA)
    cols = _columns(data, units)
    if not len(data):
        raise MsgToolsError(f"topic {data.topic} ({data.type_name}) has no messages to export")
    if not cols:
        raise MsgToolsError(
            f"topic {data.topic} ({data.type_name}) has no numeric fields to export"
        )
    header = ["time [s]", "log_time [ns]"]
    extra: List[List[str]] = []
    if data.type_name == JOINT_STATE:
        header.append("stamp [s]")
        extra.append([_ns_to_s_text(v) for v in data.fields["stamp_ns"]])
    header += [label(name, unit) for name, _, unit in cols]
    t0 = int(data.log_time_ns[0]) if len(data) else 0
    def write(target: IO[str]) -> None:
        writer = csv.writer(target, lineterminator="\n")
        writer.writerow(header)
        columns = [c.tolist() for _, c, _ in cols]
        for i, ns in enumerate(data.log_time_ns.tolist()):
            row = [_ns_to_s_text(ns - t0), str(ns)]
            row += [e[i] for e in extra]
            row += [_num(c[i]) for c in columns]
            writer.writerow(row)

    if args.out:  # whole or not at all
        with _atomic(args.out, args.force, "w") as target:
            write(target)
    else:
        try:
            write(out)
        except BrokenPipeError:
            raise
        except OSError as exc:
            raise MsgToolsError(f"cannot write stdout: {exc.strerror or exc}") from None
    if args.out:
        sys.stderr.write(f"{PROG}: wrote {len(data)} rows x {len(header)} columns to {args.out}\n")
    return 0


# ---------------------------------------------------------------------- plot
def cmd_plot(args: argparse.Namespace, out: IO[str]) -> int:
    if not 10 <= args.dpi <= 1000:  # (100,000 dpi asked for terabytes of pixels: bad_alloc)
        raise MsgToolsError(f"--dpi: 10 to 1000, got {args.dpi}")
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        raise MsgToolsError("plot needs matplotlib: pip install matplotlib") from None
    _check_out_dir(args.out, args.force, suffix=".png", bag=args.bag)
    bag = read_bag(args.bag, args.topics, keep_undecodable=True)
    units = bag.metadata_dict(UNITS_METADATA)
    for data in bag.topics.values():
        if data.decode_error:
            sys.stderr.write(f"{PROG}: warning: skipping {data.topic}: {data.decode_error}\n")
    panels: List[Tuple[str, np.ndarray, List[Tuple[str, np.ndarray]], str]] = []
    order = args.topics or sorted(bag.topics)
    starts = [int(d.log_time_ns[0]) for d in bag.topics.values() if len(d)]
    t0 = min(starts) if starts else 0
    for wanted in order:
        key = wanted if wanted in bag.topics else ("/" + wanted if "/" + wanted in bag.topics else None)
        if key is None:
            continue
        data = bag.topics[key]
        t = (data.log_time_ns - t0) * 1e-9
        cols = _columns(data, units)
        if not cols:
            continue
        if data.type_name == JOINT_STATE:
            for fname in ("position", "velocity", "effort"):
                lines = [(n[len(fname) + 1:-1], v) for n, v, _ in cols if n.startswith(fname + "[")]
                if lines:
                    panels.append((f"{data.topic} {fname}", t, lines, unit_for(data.topic, fname, units)))
        else:
            by_unit: Dict[str, List[Tuple[str, np.ndarray]]] = {}
            for name, values, unit in cols:
                by_unit.setdefault(unit, []).append((name, values))
            for unit, lines in by_unit.items():
                panels.append((data.topic, t, lines, unit))
    if not panels:
        raise MsgToolsError(f"nothing to plot: no numeric signals in {bag.path}")
    fig, axes = plt.subplots(len(panels), 1, figsize=(10, 2.4 * len(panels) + 0.6),
                             sharex=True, squeeze=False)
    for ax, (title, t, lines, unit) in zip(axes[:, 0], panels):
        step = max(1, len(t) // 200_000)
        for name, values in lines:
            ax.plot(t[::step], values[::step], lw=0.8, label=name)
        ax.set_title(title + ("" if step == 1 else f" (every {step}th sample)"), fontsize=9, loc="left")
        ax.set_ylabel(f"[{unit}]" if unit else "value")
        if is_shaft_speed(unit):
            sec = ax.secondary_yaxis(
                "right", functions=(lambda w: w * RAD_PER_S_TO_RPM, lambda n: n / RAD_PER_S_TO_RPM)
            )
            sec.set_ylabel("[rpm]")
        if len(lines) > 1:
            ax.legend(fontsize=7, loc="upper right", ncol=min(4, len(lines)))
        ax.grid(True, lw=0.3)
    axes[-1, 0].set_xlabel("time [s]")
    fig.suptitle(os.path.basename(bag.path), fontsize=10)
    fig.tight_layout()
    try:
        with _atomic(args.out, args.force, "wb") as f:
            fig.savefig(f, dpi=args.dpi, format="png")
    finally:
        plt.close(fig)
    sys.stderr.write(f"{PROG}: wrote {len(panels)} panels to {args.out}\n")
    return 0


# ------------------------------------------------------------------- compare
def cmd_compare(args: argparse.Namespace, out: IO[str]) -> int:
    from .compare import compare, compare_folders, is_bag_folder

    options = dict(topics=args.topics, rtol=args.rtol, atol=args.atol, time_base=args.time_base,
                   min_coverage=args.min_coverage, max_gap_periods=args.max_gap,
                   allow_incomplete=args.allow_incomplete)
    folders = [os.path.isdir(p) and not is_bag_folder(p) for p in (args.a, args.b)]
    if any(folders):
        if not all(folders):
            raise MsgToolsError("compare a folder of recordings with a folder of recordings, "
                                f"a recording with a recording ({args.a}, {args.b})")
        folder = compare_folders(args.a, args.b, **options)
        out.write(f"A: {folder.a_dir}\nB: {folder.b_dir} (reference)\n")
        out.write(folder.table() + "\n")
        out.write(folder.verdict() + "\n")
        return 0 if folder.passed else 1
    report = compare(args.a, args.b, **options)
    out.write(f"A: {report.a_path}\nB: {report.b_path} (reference)\n")
    out.write(report.table() + "\n")
    out.write(report.verdict() + "\n")
    return 0 if report.passed else 1


# ---------------------------------------------------------------------- main
def build_parser() -> argparse.ArgumentParser:
    """Return the argument parser of ``msg-tools``."""
    parser = _Parser(
        prog=PROG,
        description=(
            "Inspect, export, plot and compare ROS 2 MCAP recordings (rosbag2 'mcap' "
            "storage). Works without a ROS installation. Files whose recorder was "
            "killed are read up to their last complete chunk, with a warning."
        ),
        epilog=EPILOG,
        formatter_class=_Formatter,
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True

    p = sub.add_parser(
        "info", help="header, topics (type, count, rate), metadata records; checks the data",
        description=(
            "Print the header, topics with counts and rates, and the metadata records. By default "
            "the whole data section is read (streamed, one chunk at a time) and checked against the "
            "file's summary section: record lengths, decompression, chunk CRCs, the data section's "
            "CRC, chunk indexes and message counts per channel. Each problem is one 'Damage:' line, "
            "then a verdict: 'Status: complete', 'INCOMPLETE' (recorder killed: what was recovered), "
            "'RECOVERED' (a damaged record before the end, every message read through the chunk index) "
            "or 'DAMAGED'; INCOMPLETE and DAMAGED exit 1. --summary-only reads only the footer and summary section: "
            "fast, but a damaged chunk goes unseen."
        ),
        epilog=("examples:\n  msg-tools info run.mcap --qos\n"
                "  msg-tools info huge.mcap --summary-only   # no data read, nothing verified\n\n"
                "exit status: 0 complete, or recovered with every message the summary counts (a warning); "
                "1 damaged or incomplete (data lost: DAMAGED or INCOMPLETE); 2 unreadable or not MCAP"),
        formatter_class=_Formatter,
    )
    p.add_argument("bag", metavar="BAG", help="MCAP file or rosbag2 bag folder")
    p.add_argument("--summary-only", action="store_true",
                   help="read only the footer and summary section (fast); does NOT verify the data")
    p.add_argument("--qos", action="store_true", help="also print each topic's offered QoS")
    p.add_argument("--full", action="store_true", help="do not shorten long metadata values")
    p.set_defaults(func=cmd_info)

    p = sub.add_parser(
        "export", help="one topic to CSV (time in s, SI units in column names)",
        description=(
            "Write one topic as CSV. Columns: 'time [s]' since the topic's first message "
            "(log time), 'log_time [ns]' (absolute), 'stamp [s]' for JointState, then one "
            "column per value named with its SI unit, e.g. 'velocity[crank] [rad/s]'."
        ),
        epilog="example:\n  msg-tools export run.mcap --topic /joint_states --out js.csv",
        formatter_class=_Formatter,
    )
    p.add_argument("bag", metavar="BAG", help="MCAP file or rosbag2 bag folder")
    p.add_argument("--topic", "-t", required=True, help="topic to export, e.g. /drive_torque")
    p.add_argument("--out", "-o", help="CSV file to write (default: standard output); written whole or not at all")
    p.add_argument("--force", action="store_true", help="replace an existing --out file (never the bag read)")
    p.set_defaults(func=cmd_export)

    p = sub.add_parser(
        "plot", help="PNG with one panel per topic (rpm as secondary axis for speeds)",
        description=(
            "Plot topics against time [s] into a PNG, one panel per topic (per quantity "
            "for JointState). Angular speeds in rad/s get a secondary rpm axis."
        ),
        epilog="example:\n  msg-tools plot run.mcap --topics /drive_torque /joint_states --out run.png",
        formatter_class=_Formatter,
    )
    p.add_argument("bag", metavar="BAG", help="MCAP file or rosbag2 bag folder")
    p.add_argument("--topics", nargs="+", metavar="TOPIC", help="topics to plot (default: all)")
    p.add_argument("--out", "-o", required=True, help="PNG file to write (whole or not at all)")
    p.add_argument("--force", action="store_true", help="replace an existing --out file (never the bag read)")
    p.add_argument("--dpi", type=int, default=110, help="resolution, 10 to 1000 (default 110)")
    p.set_defaults(func=cmd_plot)

    p = sub.add_parser(
        "compare", help="compare A against reference B in a tolerance tube",
        description=(
            "Compare every signal of A (run under test) with B (reference): B is "
            "interpolated onto A's times (used directly when the times are identical) and "
            "each sample must satisfy |a-b| <= atol + rtol*|b|. JointState is aligned on "
            "header stamps, other types on log time. Prints the worst error per signal; "
            "a file cut off (recorder killed) fails, naming the topics whose last samples are missing, "
            "unless --allow-incomplete; exit 0 if all pass, 1 if any fails, 2 on usage or I/O errors."
        ),
        epilog=(
            "examples:\n"
            "  msg-tools compare fresh.mcap golden.mcap\n"
            "  msg-tools compare a.mcap b.mcap --topics /joint_states --rtol 1e-4 --atol 1e-6\n"
            "  msg-tools compare live.mcap sim.mcap --time-base relative\n"
            "  msg-tools compare new_runs/ golden_runs/      # folders: pairwise by file name, summary table"
        ),
        formatter_class=_Formatter,
    )
    p.add_argument("a", metavar="A", help="recording under test: MCAP file, rosbag2 bag folder, "
                                         "or a folder of recordings (compared pairwise by name)")
    p.add_argument("b", metavar="B", help="reference: the same kind as A")
    p.add_argument("--topics", nargs="+", metavar="TOPIC", help="topics to compare (default: all)")
    p.add_argument("--rtol", type=float, default=1e-6, help="relative tolerance (default 1e-6)")
    p.add_argument("--atol", type=float, default=1e-9,
                   help="absolute tolerance in each signal's SI unit (default 1e-9)")
    p.add_argument("--time-base", choices=("auto", "absolute", "relative"), default="auto",
                   help="align on the common clock, or each file from its first stamp; auto (default): the "
                        "common clock where the files' common time range covers --min-coverage of each, one base "
                        "for all signals")
    p.add_argument("--min-coverage", type=float, default=0.99,
                   help="fraction of each file's samples that must lie in their common time range (default "
                        "0.99: a run up to 1%% shorter than the other passes; 1 fails any shortfall)")
    p.add_argument("--max-gap", type=float, default=5.0, metavar="PERIODS",
                   help="fail a signal with a gap longer than this many median sample periods "
                        "(default 5; 0: no gap check) unless both files have it at the same stamps; duplicate time "
                        "stamps fail unless both files have them at the same stamps (they pair in order)")
    p.add_argument("--allow-incomplete", action="store_true",
                   help="compare a file that was cut off (recorder killed) as far as it was read; "
                        "by default it fails (exit 1) with the topics whose last samples are missing")
    p.set_defaults(func=cmd_compare)
    return parser


def main(argv: Optional[Sequence[str]] = None) -> int:
    """Run ``msg-tools`` with ``argv`` (default ``sys.argv[1:]``); return the exit status."""
    parser = build_parser()
    debug = bool(os.environ.get("MSG_TOOLS_DEBUG"))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", RecoveredBagWarning)
        try:
            args = parser.parse_args(argv)
            status = args.func(args, sys.stdout)
        except _UsageError as exc:
            sys.stderr.write(f"{PROG}: error: {exc}\n")
            return 2
        except SystemExit as exc:  # --help
            return int(exc.code or 0)
        except BrokenPipeError:  # output piped into `head`: stop quietly
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, sys.stdout.fileno())
            return 0
        except (MsgToolsError, OSError, ValueError, TypeError, KeyError) as exc:
            if debug:
                raise
            _print_warnings(caught)
            text = str(exc) if str(exc) else type(exc).__name__
            sys.stderr.write(f"{PROG}: error: {' '.join(text.split())}\n")
            return 2
        except KeyboardInterrupt:
            sys.stderr.write(f"{PROG}: interrupted\n")
            return 130
        except Exception as exc:  # noqa: BLE001 - last resort: still one line
            if debug:
                raise
            sys.stderr.write(
                f"{PROG}: error: internal error {type(exc).__name__}: {' '.join(str(exc).split())} "
                "(set MSG_TOOLS_DEBUG=1 for a traceback)\n"
            )
            return 2
    _print_warnings(caught)
    return status


def _print_warnings(caught: List[Any]) -> None:
    for item in caught:
        if not issubclass(item.category, RecoveredBagWarning):
            continue
        sys.stderr.write(f"{PROG}: warning: {' '.join(str(item.message).split())}\n")


if __name__ == "__main__":
    sys.exit(main())
