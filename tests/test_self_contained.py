"""The repository stands on its own: nothing in it points outside the clone.

Users get the repository only. The design notes and the source paper that the
developers keep in a folder beside the clone are summarised in ``docs/``; no
tracked file may refer to that folder or to the developers' machine. (The
patterns are assembled from parts so that this file does not itself contain
the paths it forbids.)
"""

import re
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
_NOTES = "sha" + "red"  # the developers' notes folder beside the clone
_WORK = "/wo" + "rk"  # the developers' machine
_MAIN = "ma" + "in"  # the developers' main checkout, beside their worktrees (a --baseline example named it)
FORBIDDEN = re.compile(rf"\.\./{_NOTES}|{_WORK}/{_NOTES}|{_NOTES}/design|{_NOTES}/seed|{_WORK}/main|{_WORK}/wt|\.\./{_MAIN}(?![\w.])")


def _tracked_text_files():
    out = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True)
    for name in out.stdout.decode().split("\0"):
        path = ROOT / name
        if not name or not path.is_file() or path.suffix in {".mcap", ".png", ".parquet"}:
            continue
        try:
            yield name, path.read_text(encoding="utf-8")
        except UnicodeDecodeError:
            continue


def test_no_tracked_file_points_outside_the_repository():
    hits = []
    for name, text in _tracked_text_files():
        for number, line in enumerate(text.splitlines(), 1):
            if FORBIDDEN.search(line):
                hits.append(f"{name}:{number}: {line.strip()[:100]}")
    assert not hits, "files point outside the repository:\n" + "\n".join(hits)


def test_the_checker_sees_a_reference():
    assert FORBIDDEN.search(f"see ../{_NOTES}/design/model.md")
    assert FORBIDDEN.search(f"python {_WORK}/main/x.py")
    assert not FORBIDDEN.search("shared memory segments of Fast DDS")
    assert FORBIDDEN.search(f"belt-drive bench kernel --baseline ../{_MAIN}  # beside another checkout")
    assert not FORBIDDEN.search(f"python ../{_MAIN}.py, ../{_MAIN}tenance")


def test_docs_carry_the_derivation_and_errata():
    model = (ROOT / "docs" / "model.md").read_text(encoding="utf-8")
    for heading in ("Lagrange", "Errata", "Sign conventions"):
        assert heading in model, heading
