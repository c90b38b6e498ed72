"""``core/warm.py``'s fallbacks with ``jobs=2`` (what ``make install`` runs): a second process that dies at once, and
one that cannot be started. The kernels' own calls are replaced by recorders here: what is checked is which of them
this process makes, in which order, and what it says (the kernels themselves: tests/test_audit_kernel.py)."""

from __future__ import annotations

import errno
import os

import pytest

from belt_drive_ros.core import jit_cache, kernel, kernel_loop, slip_run, tick, warm
from belt_drive_ros.core.network import simulate as network_simulate
from belt_drive_ros.core.network import slip as network_slip
from belt_drive_ros.core.network import tick as network_tick

#: this process's part (warm_single), then the second process's (warm_second), as recorded below
SINGLE = ["network run (wheel_steps)", "linear loop", "hybrid loop", "node ticks"]
SECOND = ["_explicit", "network slipping tier", "network tick", "variant loop"]


@pytest.fixture
def calls(monkeypatch):
    made = []

    def record(name):
        return lambda *args, **kwargs: made.append(name)

    monkeypatch.setattr(jit_cache, "refresh", record("refresh"))
    monkeypatch.setattr(warm, "_loop_arguments", lambda wheel: ())
    monkeypatch.setattr(kernel, "wheel_steps", record("wheel_steps alone"))
    monkeypatch.setattr(slip_run, "warm_events", record("event step alone"))
    for module, name, label in ((network_simulate, "warm", SINGLE[0]), (kernel_loop, "warm", SINGLE[1]),
                                (slip_run, "warm_hybrid", SINGLE[2]), (tick, "warm", SINGLE[3]),
                                (warm, "warm_explicit", SECOND[0]), (network_slip, "warm", SECOND[1]),
                                (network_tick, "warm", SECOND[2]), (kernel_loop, "warm_variants", SECOND[3])):
        monkeypatch.setattr(module, name, record(label))
    return made


def _fds() -> set:
    return set(os.listdir("/proc/self/fd"))


def test_a_second_process_that_dies_at_once_leaves_this_ones_part_whole_then_raises(calls, monkeypatch, capfd):
    """The second process exits before telling ``_explicit``: this process reads the pipe's end and goes on (its
    linear loop compiles ``_explicit`` itself, as with ``jobs=1``), told milestones go nowhere, and the exit status is
    raised once its part is done. Before, telling the dead process its first milestone raised BrokenPipeError and
    the linear loop, the hybrid loop and the node ticks were never warmed."""
    monkeypatch.setattr(warm, "SECOND", "import sys; sys.exit(3)  # {fd}")
    before = _fds()
    with pytest.raises(RuntimeError, match=r"warming the network and variant kernels failed \(exit 3\)"):
        warm.warm(jobs=2)
    assert calls == ["refresh", "wheel_steps alone", "event step alone"] + SINGLE
    assert _fds() == before  # the pipe's ends and the child's stdin closed


def test_no_second_process_to_be_had_warms_everything_here(calls, monkeypatch, capfd):
    """``jobs=2`` where no process can be started (fork refused): every kernel warmed in this process, as with
    ``jobs=1``, one line on stderr saying so, no descriptor left open. Before, the OSError ended the warm."""
    def refused(*args, **kwargs):
        raise OSError(errno.EAGAIN, os.strerror(errno.EAGAIN))

    monkeypatch.setattr(warm.subprocess, "Popen", refused)
    before = _fds()
    warm.warm(jobs=2)
    assert calls == ["refresh"] + SINGLE + SECOND
    assert capfd.readouterr().err == (f"warm: cannot start a second process ({os.strerror(errno.EAGAIN)}); "
                                      "warming every kernel in this one\n")
    assert _fds() == before


def test_jobs_1_warms_everything_here_in_the_same_order(calls):
    warm.warm(jobs=1)
    assert calls == ["refresh"] + SINGLE + SECOND
