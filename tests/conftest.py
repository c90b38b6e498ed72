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


#: Test files by their measured cost, heaviest first (``pytest --durations``; the sum of their tests' times on
#: two workers). They are collected first, each file's tests in their own order (a module fixture, such as
#: test_campaign's Dask cluster, is built once per worker as before), the other files after them in the usual
#: order. pytest-xdist's worksteal gives each worker a contiguous half of the collection and an idle worker
#: steals from the end of the other's queue: with the long tests at the front, what is left at the end is
#: short tests, so neither core waits long for the other's last test. Only the order changes: every test runs.
HEAVY_FIRST = (
    "test_docs_commands.py",
    "test_bench_cli.py",
    "test_recording_memory.py",
    "test_outputs.py",
    "test_examples.py",
    "test_campaign.py",
    "test_fuzz_campaigns.py",
    "test_accuracy_guard.py",
    "test_fuzz_scenes.py",
    "test_node_process.py",
    "test_node_shutdown.py",
    "test_msg_tools_damage.py",
    "test_foxglove.py",
    "test_recorded_steps.py",
    "test_stream.py",
    "test_replay.py",
)


def pytest_collection_modifyitems(config, items):
    """Collect the files of :data:`HEAVY_FIRST` first, in its order (a stable sort: nothing else moves)."""
    rank = {name: k for k, name in enumerate(HEAVY_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))
