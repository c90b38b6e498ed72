"""ROS-free input and output: scene and YAML files read (bounded), MCAP recordings of results, torque bags, reference bags, plots."""

import os


def is_recording(text) -> bool:
    """True when ``text`` names a recording (an ``.mcap`` file in any case, or a bag folder: :func:`holds_bag`), not a
    scene."""
    path = os.fspath(text)
    return path.lower().endswith(".mcap") or holds_bag(path)


def holds_bag(folder) -> bool:
    """True when ``folder`` is a folder holding a bag's files: an entry named ``*.mcap`` or ``metadata.yaml``, what
    :class:`msg_tools.bagdir.Ros2BagWriter` refuses to write over without ``force`` (the same test, so ``belt-drive
    sim --bag-folder`` refuses such a folder before its run, not after it)."""
    path = os.fspath(folder)
    try:
        return os.path.isdir(path) and any(f.endswith(".mcap") or f == "metadata.yaml" for f in os.listdir(path))
    except OSError:  # (unreadable: the writer's own error says why)
        return False
