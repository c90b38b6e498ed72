"""ROS-free input and output: scene and YAML files read (bounded), MCAP recordings of results, torque bags, reference bags, plots."""

import os


def is_recording(text) -> bool:
    """True when ``text`` names a recording (an ``.mcap`` file in any case, or a bag folder), not a scene."""
    path = os.fspath(text)
    if path.lower().endswith(".mcap"):
        return True
    return os.path.isdir(path) and any(f.endswith(".mcap") or f == "metadata.yaml" for f in os.listdir(path))
