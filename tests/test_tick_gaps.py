"""Gaps in the node's ticks are reported (issue 24): logged, on ``/diagnostics``, in the recording,
and by ``msg-tools info``.

A stall past the tick thread's 50 ms catch-up (simulated as in
``tests/test_tick_thread.py``: the node's lock held, as a stopped or starved
process would leave it) and a clock switch each leave ticks never made;
before, neither was logged nor flagged. One real SIGSTOP/SIGCONT of a node
process checks the same end to end.
"""

from __future__ import annotations

import io
import signal
import subprocess
import sys
import threading
import time
from contextlib import redirect_stderr, redirect_stdout

import numpy as np
import pytest

from belt_drive_ros.ros import environment as ros_env
from belt_drive_ros.ros.gaps import TickGaps
from belt_drive_ros.ros.harness import BeltDriveHarness
from belt_drive_ros.ros.timing import MAX_THREAD_CATCH_UP_NS
from msg_tools import summary
from msg_tools.cli import main as msg_tools
from msg_tools.results import TICK_GAP_METADATA, tick_gaps

TICK_NS = 1_000_000


def _info(path) -> tuple[int, str]:
    out, err = io.StringIO(), io.StringIO()
    with redirect_stdout(out), redirect_stderr(err):
        code = msg_tools(["info", str(path)])
    return code, out.getvalue()


# ------------------------------------------------------------------ no ROS
def test_gap_rules_without_ros():
    counters, lines = {}, []
    gaps = TickGaps(counters, lines.append)
    found = []
    gaps.on_gap = found.append
    gaps.tick(None, 0, TICK_NS, "system", "tick thread")  # the run starts: no gap
    for k in range(1, 5):
        gaps.tick((k - 1) * TICK_NS, k * TICK_NS, TICK_NS, "system", "tick thread")  # one period each: none
    assert counters == {"tick_gaps": 0, "ticks_missed": 0} and not found
    gaps.tick(4 * TICK_NS, 3004 * TICK_NS, TICK_NS, "system", "tick thread")  # 3 s of node time at once
    assert counters == {"tick_gaps": 1, "ticks_missed": 2999}
    gap = found[-1]
    assert (gap.start_ns, gap.end_ns, gap.missed) == (4 * TICK_NS, 3004 * TICK_NS, 2999)
    # 3 s of node time in ~0 s of monotonic time: the system clock stepped, not a stopped process
    assert "system clock stepped forward" in gap.cause and len(lines) == 1
    gaps.tick(3004 * TICK_NS, 3006 * TICK_NS, TICK_NS, "sim_time", "executor timer")  # /clock jumps: its master's
    assert counters["tick_gaps"] == 1
    gaps.switched(3006 * TICK_NS, "system", "sim_time")
    gaps.switched(None, "sim_time", "system")
    gaps.tick(None, 9_000 * TICK_NS, TICK_NS, "system", "tick thread")
    assert counters["tick_gaps"] == 2 and "system -> sim_time -> system" in found[-1].cause
    assert found[-1].metadata()["start_ns"] == str(3006 * TICK_NS)
    assert len(lines) == 1  # a second gap within a second: counted in the next line, not logged now


def test_tick_gap_records_are_listed_once_each():
    record = {"start_ns": "1", "end_ns": "5", "ticks_missed": "3", "cause": "x", "time_base": "system"}
    metadata = [("scene", {}), (TICK_GAP_METADATA, record), (TICK_GAP_METADATA, record),
                (TICK_GAP_METADATA, {**record, "start_ns": "7"})]
    assert [g["start_ns"] for g in tick_gaps(metadata)] == ["1", "7"]


# ------------------------------------------------------------------ in-process node
@pytest.mark.ros
def test_a_stall_is_a_gap_on_diagnostics_in_the_recording_and_in_msg_tools_info(ros_domain_id, tmp_path):
    path = tmp_path / "run.mcap"
    stall_ns = 4 * MAX_THREAD_CATCH_UP_NS
    with BeltDriveHarness(use_sim_time=False, domain_id=ros_domain_id, input_timeout=0.0,
                          record_path=str(path)) as h:
        node = h.node
        # every gap reported (a machine loaded far past its cores starves the thread into gaps of its own, before
        # and after the stall below: the stall's gap is the one that starts where the hold began and spans it)
        reported = []
        record = node.timing.gaps.on_gap
        node.timing.gaps.on_gap = lambda gap: (reported.append(gap), record and record(gap))
        h._spin_until(lambda: len(h._rows) >= 20, "20 ticks")
        with node.timing.lock:  # the tick thread cannot tick: a stopped or starved process
            held_from = node.integrated_ns
            time.sleep(stall_ns / 1e9)

        def stall_gap():
            return next((g for g in list(reported) if g.start_ns >= held_from
                         and g.end_ns - g.start_ns >= stall_ns - 10 * TICK_NS), None)

        h._spin_until(lambda: stall_gap() is not None, "the gap to be found")
        gap = stall_gap()
        assert gap.missed == (gap.end_ns - gap.start_ns) // TICK_NS - 1 and gap.time_base == "system"
        assert "stopped" in gap.cause and "tick thread" in gap.cause
        assert node.counters["ticks_missed"] >= gap.missed
        with node.timing.lock:
            status = {s.name: s for s in node.diagnostic_status()}["belt_drive: simulation"]
            last = node.timing.gaps.last
        values = {kv.key: kv.value for kv in status.values}
        assert int(values["tick_gaps"]) >= 1 and values["last_gap"] == last.describe()
        assert status.level == status.WARN and "gap(s) in the ticks" in status.message
    n_gaps = node.counters["tick_gaps"]  # once the node has stopped (a starved node may gap again before it does)
    records = tick_gaps(summary(path).metadata)
    assert len(records) == n_gaps
    assert any({"start_ns": str(gap.start_ns), "end_ns": str(gap.end_ns), "ticks_missed": str(gap.missed)}.items()
               <= r.items() for r in records)
    code, out = _info(path)
    assert code == 0 and f"Tick gaps:         {n_gaps} recorded by the node" in out
    assert f"{gap.missed} missed" in out


@pytest.mark.ros
def test_a_clock_switch_is_a_gap(ros_domain_id, tmp_path):
    with BeltDriveHarness(use_sim_time=False, domain_id=ros_domain_id, input_timeout=0.0) as h:
        node = h.node
        h._spin_until(lambda: len(h._rows) >= 20, "20 ticks")
        before = node.counters["tick_gaps"]
        assert h.set_parameters_over_the_service(use_sim_time=True)[0].successful
        h.spin(0.3)
        assert h.set_parameters_over_the_service(use_sim_time=False)[0].successful
        h._spin_until(lambda: node.counters["tick_gaps"] > before, "the switch's gap")
        gap = node.timing.gaps.last
        assert "clock switched (system -> sim_time -> system)" in gap.cause
        # one gap event; no tick missed: the 0.3 s between waited for /clock, the time master's (it counted ~300)
        assert gap.time_base == "system -> system" and gap.missed == 0 and "0.3" in gap.cause


# ------------------------------------------------------------------ a real SIGSTOP
def _lines(stream, into: list) -> threading.Thread:
    """A thread appending each line of ``stream`` to ``into`` until it ends."""
    thread = threading.Thread(target=lambda: into.extend(iter(stream.readline, "")), daemon=True)
    thread.start()
    return thread


def _wait(predicate, timeout: float, what: str, child) -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        assert child.poll() is None, f"the node ended (exit {child.returncode}) before {what}"
        assert time.monotonic() < deadline, f"no {what} within {timeout:g} s"
        time.sleep(0.05)


@pytest.mark.ros
def test_sigstop_of_a_recording_node_is_a_recorded_gap(tmp_path):
    """Stopped 1.5 s between ticks: one gap spanning the stop, logged, recorded and listed, its cause a stopped
    process. Paced by what the node shows (its recording growing: it ticks; the gap logged after SIGCONT), not by
    sleeps, and other gaps a starved process makes on a loaded machine may come beside it."""
    path = tmp_path / "stopped.mcap"
    domain = ros_env.process_domain_id(offset=47)
    child = subprocess.Popen([sys.executable, "-m", "belt_drive_ros.cli", "node", "paper", "--ros-args", "-p",
                              "input_timeout:=0.0", "-p", f"record_path:={path}"],
                             env=ros_env.child_environment(domain), stdout=subprocess.DEVNULL,
                             stderr=subprocess.PIPE, text=True)
    lines: list[str] = []
    reader = _lines(child.stderr, lines)
    try:
        _wait(lambda: any("spinning with" in line for line in lines) and path.exists(), 120.0, "the node spinning",
              child)
        spun = path.stat().st_size

        # 32 KiB more in the recording since: ticks' messages (1 kHz, 16 topics), not a 1 Hz diagnostics status
        _wait(lambda: path.stat().st_size > spun + 32 * 1024, 120.0, "recorded ticks", child)
        child.send_signal(signal.SIGSTOP)
        stopped_ns = time.time_ns()  # (after the signal: no tick of the node is later)
        time.sleep(1.5)
        resumed_ns = time.time_ns()  # (before it: no tick of the node after the stop is earlier)
        logged = len(lines)
        child.send_signal(signal.SIGCONT)
        _wait(lambda: any("gap in the ticks" in line for line in lines[logged:]), 120.0, "gap logged after SIGCONT",
              child)
    finally:
        child.send_signal(signal.SIGCONT)
        child.send_signal(signal.SIGINT)
        try:
            child.wait(timeout=120)
        except subprocess.TimeoutExpired:
            child.kill()
            child.wait()
        reader.join(timeout=10)
    err = "".join(lines)
    assert child.returncode == 0, err[-2000:]
    assert "gap in the ticks" in err and "stopped" in err
    records = tick_gaps(summary(path).metadata)
    # slack: a period for the grid stamps, and up to 3/4 of one more for a tick computed ahead (tick_lead, which grows
    # on a loaded machine) and published after SIGCONT: its stamp is its due time, after the stop
    spanning = [g for g in records if int(g["start_ns"]) <= stopped_ns + 2 * TICK_NS
                and int(g["end_ns"]) >= resumed_ns - TICK_NS]
    assert len(spanning) == 1, records
    assert "stopped" in spanning[0]["cause"] and int(spanning[0]["ticks_missed"]) >= 1000, records
    code, out = _info(path)
    assert code == 0 and "Tick gaps:" in out


def test_short_gaps_are_each_counted_and_handed_on_together():
    """An executor timer a few periods late (``tick_thread:=false`` on a loaded machine: ~100 a second)
    is a gap each time, counted one by one; the recording gets one aggregate record per second at most."""
    counters, found = {}, []
    gaps = TickGaps(counters, lambda line: None)
    gaps.on_gap = found.append
    t = 0
    gaps.tick(None, t, TICK_NS, "system", "executor timer")
    for k in range(100):
        gaps.tick(t, t + 3 * TICK_NS, TICK_NS, "system", "executor timer")  # 2 ticks missed each
        t += 3 * TICK_NS
    assert counters == {"tick_gaps": 100, "ticks_missed": 200} and found == []  # collected, not yet handed on
    assert "ran 3 ms after the last tick" in gaps.last.cause
    gaps.tick(t, t + 2_000 * TICK_NS, TICK_NS, "system", "tick thread")  # a long one: the short ones first
    assert [g.missed for g in found] == [200, 1999]
    assert found[0].start_ns == 0 and found[0].end_ns == 300 * TICK_NS and "100 short gaps" in found[0].cause
    gaps.tick(t + 2_000 * TICK_NS, t + 2_003 * TICK_NS, TICK_NS, "system", "executor timer")
    gaps.flush()  # the node's end
    assert found[-1].missed == 2 and len(found) == 3


def test_a_tick_source_behind_its_ticks_is_not_a_clock_step():
    """A tick thread that fell behind (ticks each slower than 1 ms: Radau, a starved CPU) makes its usual ticks late,
    the last one just now: its gap's node time was read as 'the system clock stepped forward' (21 of 32 records)
    since little monotonic time had passed since that tick. The clock moved by what monotonic time did: starved."""
    import time

    counters, found = {}, []
    gaps = TickGaps(counters, lambda line: None)
    gaps.on_gap = found.append
    gaps.tick(None, 0, TICK_NS, "system", "tick thread")
    # the thread's usual tick of node time 4 ms, made when the system clock read 100 ms (96 ms behind)
    gaps.mono, gaps.real = time.monotonic_ns(), 100 * TICK_NS
    gaps.tick(4 * TICK_NS, 104 * TICK_NS, TICK_NS, "system", "tick thread")  # it gives up: the latest tick
    assert "starved of CPU" in found[-1].cause and "stepped" not in found[-1].cause
