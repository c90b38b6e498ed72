"""Private ROS domain ids: concurrent processes on one machine never hold the same id."""

import fcntl
import os
import subprocess
import sys
from pathlib import Path

from belt_drive_ros.ros import environment as ros_env

ROOT = Path(__file__).resolve().parent.parent

#: a child that takes ids for offsets 0 and 1 (and 0 again), prints them, and holds them until its stdin closes
HOLDER = (
    "import sys\n"
    "from belt_drive_ros.ros.environment import process_domain_id\n"
    "ids = [process_domain_id(), process_domain_id(offset=1), process_domain_id()]\n"
    "print(*ids, flush=True)\n"
    "sys.stdin.read()\n"
)


def _start_holder() -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-c", HOLDER], cwd=ROOT, stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True, env=ros_env.child_environment(0))


def _lockable(domain: int) -> bool:
    """Whether nobody holds ``domain``'s lock file now (probed with flock directly, then released)."""
    fd = os.open(ros_env.domain_lock_dir() / f"{domain}.lock", os.O_RDONLY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        return True
    except BlockingIOError:
        return False
    finally:
        os.close(fd)


def test_concurrent_processes_hold_different_domain_ids():
    mine = {ros_env.process_domain_id(), ros_env.process_domain_id(offset=1)}
    holders = [_start_holder() for _ in range(3)]
    try:
        held = [tuple(int(x) for x in p.stdout.readline().split()) for p in holders]
    finally:
        for p in holders:
            p.stdin.close()
            p.wait(timeout=30)
    lo, hi = ros_env.DOMAIN_ID_RANGE
    for first, second, again in held:
        assert again == first  # the same offset gives the same id for the life of the process
        assert first != second
    every = [d for ids in held for d in ids[:2]] + sorted(mine)
    assert len(set(every)) == len(every), held  # no two holders (nor this process) share an id
    assert all(lo <= d <= hi for d in every) and 0 < lo and hi <= 101  # Fast DDS's port mapping on Linux
    assert all(p.returncode == 0 for p in holders)


def test_an_id_is_held_while_its_process_lives_and_free_once_it_has_ended():
    holder = _start_holder()
    first, second, _ = (int(x) for x in holder.stdout.readline().split())
    assert not _lockable(first) and not _lockable(second)
    holder.kill()  # however it ends, the kernel releases its locks
    holder.wait(timeout=30)
    holder.stdin.close()
    assert _lockable(first) and _lockable(second)


def test_orphan_fast_dds_segments_are_removed_and_segments_in_use_are_kept():
    """What a killed participant leaves in /dev/shm goes; a segment a live process holds, and the
    shared port segments, stay."""
    import secrets

    from belt_drive_ros.ros import environment as ros_env

    orphan, held = (f"fastrtps_{secrets.token_hex(8)}" for _ in range(2))
    port = f"fastrtps_port{secrets.randbelow(10**6) + 10**6}"
    paths = [os.path.join(ros_env.SHM_DIR, n) for n in (orphan, orphan + "_el", held, port)]
    for p in paths:
        open(p, "wb").close()
    keep_open = open(paths[2], "rb")  # a live process (this one) has it open
    try:
        assert {orphan, orphan + "_el", held} <= ros_env.fast_dds_segments()
        assert port not in ros_env.fast_dds_segments()
        removed = ros_env.remove_orphan_segments({orphan, orphan + "_el", held, port})
        assert removed == {orphan, orphan + "_el"}
        assert [os.path.exists(p) for p in paths] == [False, False, True, True]
    finally:
        keep_open.close()
        for p in paths:
            if os.path.exists(p):
                os.unlink(p)
