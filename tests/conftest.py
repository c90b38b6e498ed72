"""Shared test set-up: DDS stays on loopback; each test process holds its own ROS domain.

The discovery range is set here, before any test module imports rclpy, so
every context a test initialises discovers only this machine (unless the
person running the tests chose a range themselves). ``ROS_LOCALHOST_ONLY``
is deprecated in Jazzy and never set.
"""

import os

from belt_drive_ros.ros.environment import (
    configure_environment,
    fast_dds_segments,
    process_domain_id,
    remove_orphan_segments,
)

configure_environment(loopback=True)
os.environ.setdefault("MPLBACKEND", "Agg")
# when the suite started (the first process to read this file: pytest-xdist's workers inherit it): a kernel's
# disk-cache entry written after it was compiled by a test, not by ``make install``
# (test_audit_kernel.test_the_first_runs_after_install_compile_nothing)
os.environ.setdefault("BELT_DRIVE_SUITE_START", repr(__import__("time").time()))

import signal  # noqa: E402

import pytest  # noqa: E402

# A suite started in the background of a shell without job control (``make test &``, ``nohup``, a CI
# runner's step) inherits SIGINT ignored, and Python then keeps it ignored instead of installing its
# KeyboardInterrupt handler. The suite runs as from a terminal whatever started it: the Ctrl-C tests
# expect KeyboardInterrupt here, and the processes they start get SIGINT's default action. (Three
# test_campaign tests failed in every backgrounded fresh clone for this alone.)
if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)


@pytest.fixture(scope="session")
def ros_domain_id() -> int:
    """A ROS domain id private to this pytest process, locked for its life (ROS_DOMAIN_ID is ignored).

    See :func:`belt_drive_ros.ros.environment.process_domain_id`: concurrent
    suites on one machine (other worktrees, other users) never share it.
    Child processes a test starts get it through ``child_environment``.
    """
    return process_domain_id()


@pytest.fixture(scope="session", autouse=True)
def no_orphan_shared_memory():
    """After the session: remove the Fast DDS segments left in /dev/shm by processes the tests killed.

    Only segments that appeared during the session and that no live process
    (another suite's included) has mapped or open.
    """
    before = fast_dds_segments()
    yield
    remove_orphan_segments(fast_dds_segments() - before)


def pytest_collection_modifyitems(items):
    """The check that the first runs after ``make install`` compile nothing runs first (on the first worker):
    a later test that compiled a kernel ``make install`` missed would have written it to the cache before."""
    first = [item for item in items if item.name == "test_the_first_runs_after_install_compile_nothing"]
    items[:] = first + [item for item in items if item not in first]
