"""A ``sim --bag-folder F --force`` killed outright (SIGKILL: no ``finally`` runs) leaves the old bag set aside in a
hidden ``.F.*.old`` beside ``F``. Before, it stayed there for ever, and the next run never looked; now the next run
into ``F`` settles it first and says so on stderr: the old bag put back when ``F`` holds no whole bag (the killed
run's unfinished files removed), the set-aside copy removed when ``F``'s bag is whole (the killed run finished it)."""

from __future__ import annotations

import hashlib
import os
import shutil
import signal
import subprocess
import sys
import time

from belt_drive_ros.cli import main

SHORT = ["sim", "paper", "--duration", "0.05", "--quiet", "--bag-folder"]


def _digests(folder):
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(folder.iterdir()) if p.is_file()}


def _run(argv, capsys):
    status = main([str(a) for a in argv])
    return status, capsys.readouterr().err.strip().splitlines()


def test_a_killed_force_run_s_old_bag_is_put_back_by_the_next_run(tmp_path, capsys):
    folder = tmp_path / "F"
    assert _run(SHORT + ["--out", folder], capsys)[0] == 0
    old = _digests(folder)
    # a streamed --force run into F, killed outright once it has set the old bag aside (its new bag begun or not yet)
    child = subprocess.Popen([sys.executable, "-m", "belt_drive_ros.cli", "sim", "paper", "--duration", "100000",
                              "--quiet", "--bag-folder", "--out", str(folder), "--force"],
                             stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 300
        while not list(tmp_path.glob(".F.*.old")):
            assert child.poll() is None, child.stderr.read().decode()
            assert time.monotonic() < deadline, "the child never began its bag"
            time.sleep(0.05)
    finally:
        child.send_signal(signal.SIGKILL)
        child.wait()
        child.stderr.close()
    aside = list(tmp_path.glob(".F.*.old"))
    assert len(aside) == 1 and _digests(aside[0]) == old  # what the kill leaves: the old bag beside F
    unfinished = sorted(p.name for p in folder.iterdir())
    assert unfinished in ([], ["F_0.mcap"])  # the new bag not begun, or unfinished (no metadata.yaml)
    # the next run (without --force): puts the old bag back, then refuses to replace it as it would any bag
    status, err = _run(SHORT + ["--out", folder], capsys)
    assert err[0] == (f"belt-drive: --out {folder}: put back the bag a run killed while replacing it had set aside in "
                      f"{aside[0].name}" + (" (the 1 unfinished files it wrote, without metadata.yaml, removed)"
                                            if unfinished else "")), err
    assert status == 2 and "--force" in err[-1], err
    assert _digests(folder) == old and sorted(p.name for p in tmp_path.iterdir()) == ["F"]


def test_a_set_aside_bag_beside_a_whole_bag_is_removed_by_the_next_run(tmp_path, capsys):
    """The killed run finished F's new bag (its metadata.yaml written) but not its clean-up: the old copy goes."""
    folder = tmp_path / "F"
    assert _run(SHORT + ["--out", folder], capsys)[0] == 0
    aside = tmp_path / ".F.x1y2z3.old"
    shutil.copytree(folder, aside)
    os.utime(folder / "metadata.yaml", (1, 1))
    whole = _digests(folder)
    status, err = _run(["sim", "paper", "--duration", "0.1", "--quiet", "--bag-folder", "--out", folder, "--force"],
                       capsys)
    assert status == 0 and err == [f"belt-drive: --out {folder}: removed .F.x1y2z3.old, the bag it held before a run "
                                   "that was killed after writing this one (whole: its metadata.yaml is written) had "
                                   "set aside"], err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["F"] and _digests(folder) != whole  # (the new run's bag)
    # a folder with no leftover beside it: nothing said
    assert _run(["sim", "paper", "--duration", "0.05", "--quiet", "--bag-folder", "--out", folder, "--force"],
                capsys) == (0, [])


def test_a_set_aside_bag_replaces_the_unfinished_files_of_the_run_that_was_killed(tmp_path, capsys):
    """The state of a kill after the new bag's first file was begun: F holds it without metadata.yaml."""
    folder = tmp_path / "F"
    assert _run(SHORT + ["--out", folder], capsys)[0] == 0
    old = _digests(folder)
    aside = tmp_path / ".F.a1b2c3.old"
    folder.rename(aside)
    folder.mkdir()
    (folder / "F_0.mcap").write_bytes(b"\x89MCAP0\r\n")  # (what a writer killed at once leaves)
    (folder / "notes.txt").write_text("mine")  # (not a bag writer's: stays)
    status, err = _run(["sim", "paper", "--duration", "0.1", "--quiet", "--bag-folder", "--out", folder], capsys)
    assert err[0] == (f"belt-drive: --out {folder}: put back the bag a run killed while replacing it had set aside in "
                      ".F.a1b2c3.old (the 1 unfinished files it wrote, without metadata.yaml, removed)"), err
    assert status == 2 and sorted(p.name for p in tmp_path.iterdir()) == ["F"]
    assert _digests(folder) == dict(old, **{"notes.txt": hashlib.sha256(b"mine").hexdigest()})
