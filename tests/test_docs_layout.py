"""docs/development.md describes the tree as it is: one line per module, no module that is gone."""

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DOC = ROOT / "docs" / "development.md"


def _modules() -> set:
    """Every module of the package (relative to belt_drive_ros/) and of msg_tools/ (with its prefix)."""
    found = set()
    for path in (ROOT / "belt_drive_ros").rglob("*.py"):
        rel = path.relative_to(ROOT / "belt_drive_ros").as_posix()
        if path.name != "__init__.py" and "/" in rel:  # top-level cli.py and testing.py: named in the text
            found.add(rel)
    for path in (ROOT / "msg_tools").glob("*.py"):
        if path.name != "__init__.py":
            found.add(f"msg_tools/{path.name}")
    return found


def test_every_module_has_its_line():
    text = DOC.read_text()
    missing = sorted(m for m in _modules() if f"`{m}`" not in text)
    assert not missing, f"docs/development.md: no line for {', '.join(missing)}"


def test_every_module_named_exists():
    text = DOC.read_text()
    named = set(re.findall(r"`((?:core|io|ros|commands|benchmarks|msg_tools)/[a-z_]+\.py)`", text))
    assert named, "the pattern found no module names: the check would pass vacuously"
    gone = sorted(m for m in named if not ((ROOT / "belt_drive_ros" / m).is_file() or (ROOT / m).is_file()))
    assert not gone, f"docs/development.md names modules that do not exist: {', '.join(gone)}"
