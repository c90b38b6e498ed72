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

import pytest  # noqa: E402


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
