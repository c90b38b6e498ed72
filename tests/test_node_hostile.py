"""Hostile values for the node's ``scene`` parameter, set over the SetParameters service (issue 13 item 1).

Any process in the domain can set ``scene``. ``/dev/zero`` used to be read
until memory ran out and a FIFO made the call never return (output stopped,
SIGTERM ignored). Each is now refused promptly with the reason, the old
scene is kept and the node goes on ticking. A test that hung would be a
failure: every service call is bounded by the harness's wait.
"""

from __future__ import annotations

import os
import signal
from contextlib import contextmanager

import pytest

from belt_drive_ros.ros.harness import BeltDriveHarness

pytestmark = pytest.mark.ros


@contextmanager
def _no_hang(seconds: float):
    """Fail (TimeoutError) instead of hanging if the body blocks, e.g. in open() on a FIFO."""
    def hang(signum, frame):
        raise TimeoutError(f"still blocked after {seconds} s")

    previous = signal.signal(signal.SIGALRM, hang)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


def _set_scene_over_the_service(h, value: str):
    """SetParameters(scene=value) through DDS from the harness's probe node; the result."""
    return h.set_parameters_over_the_service(scene=value)[0]


def test_hostile_scene_values_are_refused_promptly_and_the_node_keeps_running(ros_domain_id, tmp_path):
    fifo = tmp_path / "scene.fifo"
    os.mkfifo(fifo)  # nobody ever writes: opening it for reading would block
    big = tmp_path / "big.yaml"
    big.write_bytes(b"# " + b"x" * (64 * 2**20))
    binary = tmp_path / "binary.yaml"
    binary.write_bytes(bytes(range(256)) * 8)
    bomb = tmp_path / "bomb.yaml"
    bomb.write_text("a: &a [1, 1, 1, 1, 1, 1, 1, 1, 1]\n" + "".join(
        f"{chr(98 + k)}: &{chr(98 + k)} [" + ", ".join([f"*{chr(97 + k)}"] * 9) + "]\n" for k in range(8)))
    hostile = {"/dev/zero": "regular file", str(fifo): "regular file", str(tmp_path): "regular file",
               str(big): "more than the limit", str(binary): "UTF-8", str(bomb): "anchors"}
    with _no_hang(120.0), BeltDriveHarness(domain_id=ros_domain_id, input_timeout=0.0) as h:
        h.publish_torque(3.0)
        h.advance(0.01)
        for value, reason in hostile.items():
            result = _set_scene_over_the_service(h, value)
            assert not result.successful, value
            assert result.reason.startswith("scene:") and reason.lower() in result.reason.lower(), (value, result.reason)
            assert len(result.reason) < 400, result.reason  # quoted values are cut short
            assert h.node.get_parameter("scene").value == "paper"
        n = h.outputs()["time"].size
        h.advance(0.01)
        assert h.outputs()["time"].size == n + 10  # ticking on the old scene
        assert h.node.settings.scene.name == "paper"


def test_names_the_os_refuses_are_answered_with_a_reason_and_the_node_keeps_ticking(ros_domain_id, tmp_path):
    """Issue 24: a ``scene`` of 300 characters without a slash raised "File name too long" inside the
    callback; the node's executor ended (exit 1) and the SetParameters call was never answered."""
    fifo = tmp_path / "x.fifo"
    os.mkfifo(fifo)
    hostile = {
        "a" * 300: "unknown scene",                                  # too long a name, no slash
        "b" * 5000: "unknown scene",                                 # far longer than PATH_MAX
        str(tmp_path / ("c" * 300)) + ".yaml": "file name too long",  # one component past 255 bytes
        "/".join(["d" * 200] * 30) + ".yaml": "file name too long",  # the whole path past PATH_MAX
        str(tmp_path): "directory",
        str(fifo): "fifo",
        "/dev/zero": "character device",
    }
    with _no_hang(120.0), BeltDriveHarness(domain_id=ros_domain_id, input_timeout=0.0) as h:
        h.advance(0.01)
        for value, reason in hostile.items():
            result = _set_scene_over_the_service(h, value)
            assert not result.successful, value[:80]
            assert reason in result.reason.lower(), (value[:80], result.reason)
            assert result.reason.startswith("scene:") and len(result.reason) < 400, result.reason
            assert h.node.get_parameter("scene").value == "paper"
        n = h.outputs()["time"].size
        h.advance(0.01)
        assert h.outputs()["time"].size == n + 10  # ticking on the old scene
        # strings the wire cannot carry (DDS strings end at a NUL; unpaired surrogates are not UTF-8)
        # reach the callbacks only in-process: refused with a reason there too, never raised
        from rclpy.parameter import Parameter

        for value, reason in {"x\x00y": "unknown scene", str(tmp_path / "x\x00y.yaml"): "nul byte",
                              "\ud800.yaml": "cannot be encoded", "\udcff" * 300: "unknown scene",
                              "\ud800": "unknown scene"}.items():
            result = h.node.set_parameters([Parameter("scene", value=value)])[0]
            assert not result.successful and result.reason.startswith("scene:"), (value, result.reason)
            assert reason in result.reason.lower(), (value[:80], result.reason)
        h.advance(0.01)
        assert h.outputs()["time"].size == n + 20


def test_an_unexpected_exception_in_the_callbacks_is_an_answer_not_the_end_of_the_node(ros_domain_id, monkeypatch):
    """Whatever fails inside validation (here: a RuntimeError injected into it) is a refusal with the
    reason; a failure while applying an accepted change is logged; the node keeps ticking either way."""
    from belt_drive_ros.ros import parameters

    def boom(*args, **kwargs):
        raise RuntimeError("injected failure")

    with _no_hang(120.0), BeltDriveHarness(domain_id=ros_domain_id, input_timeout=0.0) as h:
        h.advance(0.01)
        k = h.node.get_parameter("k").value
        with monkeypatch.context() as m:
            m.setattr(parameters, "build_settings", boom)
            result = h.set_parameters_over_the_service(k=k * 1.1)[0]
        assert not result.successful and "RuntimeError: injected failure" in result.reason
        assert h.node.get_parameter("k").value == k
        h.node.node_parameters._apply = boom
        result = h.set_parameters_over_the_service(k=k * 1.2)[0]
        assert result.successful  # validated and set; applying it failed, which the log says
        n = h.outputs()["time"].size
        h.advance(0.01)
        assert h.outputs()["time"].size == n + 10
