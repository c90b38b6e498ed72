"""Scene files read: a drive's scene (:func:`load_scene`) or a belt network's (:func:`load_network`), by shipped name
(``belt_drive_ros/scenes``, ``scenes/networks``) or by path, through the bounded reader of :mod:`.inputs`; the core
builds and checks the scene from the parsed mapping (:class:`~belt_drive_ros.core.scene.Scene`,
:class:`~belt_drive_ros.core.network.scene.NetworkScene`).
"""

from __future__ import annotations

import copy
import os
import stat
from importlib import resources
from pathlib import Path
from typing import Any, Mapping

import yaml

from ..core.errors import SceneError, short
from ..core.network.scene import NetworkScene
from ..core.scene import Scene, shipped_scenes
from .inputs import parse_yaml, read_text

__all__ = ["is_network", "load_either_scene", "load_network", "load_scene", "scene_from_mapping", "scene_yaml", "shipped_networks", "shipped_scenes"]


#: the last scene file parsed, ``[(label, text), mapping]``: a command asks :func:`is_network` of a file, then loads
#: it; with the pure-Python YAML parser that second parse was half of a small run's start (and of the scene fuzz test)
_LAST_PARSE: list = [None, None]


def _parse_file(path: Path, label: str) -> Any:
    """The scene file ``path`` read (:func:`.inputs.read_text`, every time) and parsed (:func:`.inputs.parse_yaml`),
    or a copy of the last parse if its text and label are the same."""
    text = read_text(path, "scene file")
    if _LAST_PARSE[0] == (label, text):
        return copy.deepcopy(_LAST_PARSE[1])
    data = parse_yaml(text, label)
    _LAST_PARSE[:] = [(label, text), copy.deepcopy(data)]  # (a copy: a caller may change what it was given)
    return data


def _shipped_text(name: str, folder: str = "") -> str:
    return (resources.files("belt_drive_ros") / "scenes" / folder / f"{name}.yaml").read_text(encoding="utf-8")


def scene_from_mapping(data: Mapping[str, Any], name: str | None = None) -> Scene:
    """:meth:`Scene.from_mapping <belt_drive_ros.core.scene.Scene.from_mapping>`, ``extends: NAME`` read from the
    shipped scene ``NAME``."""
    return Scene.from_mapping(data, name=name, shipped=load_scene)


def load_scene(name_or_path: str | Path) -> Scene:
    """Scene by shipped name (``paper``) or by path to a YAML file (read through :mod:`.inputs`); the scene must
    state its keys or ``extends`` a shipped one."""
    if not isinstance(name_or_path, (str, Path)):
        raise SceneError(f"scene: expected a name or a path, got {type(name_or_path).__name__} {short(name_or_path)}")
    label = str(name_or_path)
    path = Path(name_or_path)
    if label and (path.suffix in (".yaml", ".yml") or os.path.lexists(path) or os.sep in label):  # ('' is Path('.'))
        data = _parse_file(path, f"scene file {short(label, 200)}")
        if isinstance(data, Mapping) and data.get("kind") == "network":
            raise _network_here(label)
        return scene_from_mapping(data, name=path.stem)
    names = shipped_scenes()
    if label in shipped_networks():
        raise _network_here(label)
    if label not in names:  # compared by name: a name the OS refuses (too long, NUL) never reaches it
        raise SceneError(f"unknown scene {short(label)}: not a file and not a shipped scene ({', '.join(names)})")
    return scene_from_mapping(parse_yaml(_shipped_text(label), label), name=label)


def _network_here(label: str) -> SceneError:
    """The refusal of a belt network where a drive scene is read (the paper node's ``scene``, a campaign's base)."""
    return SceneError(f"scene {short(label)}: a belt network (kind: network), not a drive scene: it runs on its own "
                      f"node, started with it (belt-drive node {label[:200]}), and offline with belt-drive sim")


def load_either_scene(name_or_path: str | Path) -> Scene:
    """:func:`load_scene` for a command that takes a belt network too (``sim``, ``urdf``; the network named is the
    caller's to load first): an unknown name's message lists the shipped belt networks beside the drive scenes."""
    try:
        return load_scene(name_or_path)
    except SceneError as exc:
        if str(exc).startswith("unknown scene"):
            raise SceneError(f"{exc}; nor a shipped belt network ({', '.join(shipped_networks())})") from None
        raise


def scene_yaml(scene: Scene) -> str:
    """The scene as YAML (what ``belt-drive scenes NAME`` prints; loads back to an equal scene)."""
    return yaml.safe_dump(scene.to_dict(), sort_keys=False)


def shipped_networks() -> list[str]:
    """Names of the network scenes shipped in the package (``belt_drive_ros/scenes/networks``)."""
    return shipped_scenes("networks")


def is_network(name_or_path: str | Path) -> bool:
    """Whether ``name_or_path`` names a shipped network scene or a YAML file stating ``kind: network``."""
    label = str(name_or_path)
    if label in shipped_networks():
        return True
    path = Path(label)
    if path.suffix.lower() in (".mcap", ".csv", ".png"):  # (any other name of a regular file is a scene's: looked into)
        return False
    try:
        regular = stat.S_ISREG(os.stat(path).st_mode)
    except (OSError, ValueError):  # a name the OS refuses (too long, NUL byte ...): the scene loader says so in one line
        return False
    if regular:
        data = _parse_file(path, f"scene file {short(label, 200)}")
        return isinstance(data, Mapping) and data.get("kind") == "network"
    return False


def load_network(name_or_path: str | Path) -> NetworkScene:
    """A network scene by shipped name or path (read like every scene file: regular, UTF-8, size-limited)."""
    if not isinstance(name_or_path, (str, Path)):
        raise SceneError(f"scene: expected a name or a path, got {type(name_or_path).__name__} {short(name_or_path)}")
    label = str(name_or_path)
    if label in shipped_networks():
        text, default, where = _shipped_text(label, "networks"), label, label
    else:
        path = Path(label)
        if not label or not (path.suffix in (".yaml", ".yml") or os.path.lexists(path)):  # ('' is Path('.'))
            raise SceneError(f"unknown network scene {short(label)}: not a file and not shipped ({', '.join(shipped_networks())})")
        text, default, where = None, path.stem, f"scene file {short(label, 200)}"
    data = parse_yaml(text, where) if text is not None else _parse_file(path, where)
    if not isinstance(data, Mapping):
        raise SceneError(f"{where}: expected a mapping, got {type(data).__name__}")
    return NetworkScene.from_mapping(data, name=default)
