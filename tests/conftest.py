"""Shared test set-up: DDS stays on loopback; each test process gets its own ROS domain.

The variables are set here, before any test module imports rclpy, so every
context a test initialises discovers only this machine.
"""

import os

os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
os.environ.setdefault("ROS_LOCALHOST_ONLY", "1")
os.environ.setdefault("MPLBACKEND", "Agg")

import pytest  # noqa: E402


@pytest.fixture(scope="session")
def ros_domain_id() -> int:
    """A ROS domain id private to this pytest process (1 + pid % 100; ROS_DOMAIN_ID is ignored)."""
    return 1 + os.getpid() % 100
