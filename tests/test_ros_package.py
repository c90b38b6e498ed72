"""The ROS 2 package: ``colcon build`` in a fresh workspace installs what ``ros2 run`` / ``ros2 launch`` look for.

A copy of the package's sources is built with colcon (colcon-core,
colcon-ros, colcon-python-setup-py: pinned in constraints.txt) into a
temporary workspace. The install must hold the ament index marker,
``share/belt_drive_ros/package.xml``, the launch and parameter files, and
the executables ``lib/belt_drive_ros/node`` and ``source``; run with the
workspace's own environment (``install/local_setup.sh``) they must start
and import the installed copy. A wheel of the same sources must not carry
those executables (pip would put a ``node`` on the PATH). Takes ~5 s.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = "belt_drive_ros"
#: what the package is built from (pyproject.toml's readme is README.md)
SOURCES = ("package.xml", "setup.py", "setup.cfg", "pyproject.toml", "README.md",
           "resource", "launch", "config", PACKAGE, "msg_tools")
#: the package's executables in lib/belt_drive_ros and the belt-drive command each one is
EXECUTABLES = {"node": "belt-drive node", "source": "belt-drive source"}


def _copy_sources(dest: Path) -> Path:
    pkg = dest / "src" / PACKAGE
    pkg.mkdir(parents=True)
    for name in SOURCES:
        src = ROOT / name
        if src.is_dir():
            shutil.copytree(src, pkg / name, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
        else:
            shutil.copy2(src, pkg / name)
    return pkg


def _clean_env(tmp: Path) -> dict:
    """The test's environment without any ROS workspace in it (a sourced workspace would be an underlay)."""
    env = {k: v for k, v in os.environ.items()
           if k not in ("AMENT_PREFIX_PATH", "COLCON_PREFIX_PATH", "CMAKE_PREFIX_PATH", "PYTHONPATH")}
    env["COLCON_HOME"] = str(tmp / "colcon_home")  # no user defaults or mixins
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    return env


def _build(ws: Path, *options: str) -> tuple:
    """``colcon build`` (with ``options``) of a copy of the sources in the workspace ``ws``."""
    _copy_sources(ws)
    env = _clean_env(ws)
    colcon = Path(sys.executable).parent / "colcon"
    proc = subprocess.run(
        [str(colcon), "--log-base", str(ws / "log"), "build", *options, "--base-paths", str(ws / "src"),
         "--build-base", str(ws / "build"), "--install-base", str(ws / "install"),
         "--event-handlers", "console_direct-"],
        cwd=ws, env=env, capture_output=True, text=True, timeout=300,
    )
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    return ws, env, proc.stdout + proc.stderr


@pytest.fixture(scope="module")
def workspace(tmp_path_factory):
    """A colcon workspace with the package built (``colcon build``, no symlink install)."""
    return _build(tmp_path_factory.mktemp("ws"))


def _in_workspace(ws: Path, env: dict, command: str) -> subprocess.CompletedProcess:
    """Run ``command`` with the workspace's environment (``. install/local_setup.sh``) in ``sh``."""
    return subprocess.run(["sh", "-c", f". {ws}/install/local_setup.sh && {command}"], cwd=ws, env=env,
                          capture_output=True, text=True, timeout=120)


def _lib(ws: Path) -> str:
    """The folder ``ros2 run`` takes the package's executables from."""
    return str(ws / "install" / PACKAGE / "lib" / PACKAGE)


def test_colcon_finds_the_ros_package_and_installs_its_files(workspace):
    ws, _, log = workspace
    prefix = ws / "install" / PACKAGE
    assert "Finished <<< belt_drive_ros" in log
    assert "doesn't explicitly install" not in log  # marker and package.xml installed by setup.py, not colcon's fallback
    assert (prefix / "share" / "ament_index" / "resource_index" / "packages" / PACKAGE).is_file()
    manifest = prefix / "share" / PACKAGE / "package.xml"
    assert manifest.read_bytes() == (ROOT / "package.xml").read_bytes()
    assert (prefix / "share" / PACKAGE / "launch" / "belt_drive.launch.py").is_file()
    assert (prefix / "share" / PACKAGE / "config" / "belt_drive.yaml").is_file()
    for name in EXECUTABLES:
        exe = prefix / "lib" / PACKAGE / name
        assert exe.is_file() and os.access(exe, os.X_OK), exe


def test_package_xml_is_format_3_with_the_dependencies_the_code_imports():
    root = ET.parse(ROOT / "package.xml").getroot()
    assert root.tag == "package" and root.get("format") == "3"
    assert root.findtext("name") == PACKAGE
    assert root.find("export").findtext("build_type") == "ament_python"
    deps = {e.text for e in root.iter("exec_depend")}
    for dep in ("rclpy", "std_msgs", "sensor_msgs", "diagnostic_msgs", "rosgraph_msgs", "builtin_interfaces",
                "std_srvs", "launch_ros", "python3-numpy", "python3-scipy", "python3-yaml"):
        assert dep in deps, dep
    # every ROS message package the node's code imports is declared
    imported = set()
    for path in (ROOT / PACKAGE).rglob("*.py"):
        for line in path.read_text(encoding="utf-8").splitlines():
            words = line.split()
            if len(words) >= 2 and words[0] in ("from", "import") and (
                    words[1].split(".")[0].endswith(("_msgs", "_srvs", "_interfaces"))):  # (rcl_interfaces too)
                imported.add(words[1].split(".")[0])
    assert imported and imported <= deps | {"tf2_msgs"}, imported - deps  # tf2_msgs: used only where importable
    # the plots' and campaigns' libraries the package imports, and the suite's with a rosdep key
    for dep in ("python3-matplotlib", "python3-pandas"):
        assert dep in deps, dep
    tests = {e.text for e in root.iter("test_depend")}
    assert {"python3-pytest", "python3-pytest-xdist", "python3-sympy"} <= tests, tests


def test_the_build_takes_the_license_from_setup_py_as_a_system_ros_2s_setuptools_reads_it(workspace):
    """colcon under a system ROS 2 Jazzy runs ``setup.py`` with the distro's setuptools (Ubuntu 24.04: 68.1.2),
    whose pyproject.toml schema takes ``project.license`` only as a table: the SPDX string (setuptools >= 77)
    stopped every build there ('`project.license` must be valid exactly by one definition'), and >= 77 deprecates
    the table. The license is setup.py's (``dynamic``), installed as package.xml states it."""
    import tomllib

    project = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    assert "license" not in project and "license" in project.get("dynamic", []), project.get("license")
    expected = ET.parse(ROOT / "package.xml").getroot().findtext("license")
    ws, _, _ = workspace
    (pkg_info,) = (ws / "install" / PACKAGE).rglob("belt_drive_ros-*.egg-info/PKG-INFO")
    assert f"License: {expected}" in pkg_info.read_text(encoding="utf-8").splitlines()


def test_installed_executables_run_from_the_workspace_environment(workspace):
    ws, env, _ = workspace
    for name, command in EXECUTABLES.items():
        proc = _in_workspace(ws, env, f"{_lib(ws)}/{name} --help")
        assert proc.returncode == 0, proc.stderr
        assert proc.stdout.startswith(f"usage: {command}"), proc.stdout[:200]
    proc = _in_workspace(ws, env, f"{_lib(ws)}/node --list-parameters")
    assert proc.returncode == 0 and "record_path" in proc.stdout, proc.stderr
    # the executables import the workspace's copy of the package, not the development tree
    proc = _in_workspace(ws, env, f"{sys.executable} -c 'import belt_drive_ros; print(belt_drive_ros.__file__)'")
    assert proc.stdout.strip().startswith(str(ws / "install" / PACKAGE)), proc.stdout + proc.stderr


def test_ament_index_finds_the_package_and_its_executables_as_ros2_run_does(workspace):
    """``ros2 run PKG EXE`` runs ``<prefix of PKG in the ament index>/lib/PKG/EXE``."""
    ws, env, _ = workspace
    code = (
        "import os; from ament_index_python.packages import get_package_prefix, get_package_share_directory; "
        f"p = get_package_prefix('{PACKAGE}'); print(p); print(get_package_share_directory('{PACKAGE}')); "
        f"print(sorted(f for f in os.listdir(os.path.join(p, 'lib', '{PACKAGE}')) "
        f"if os.access(os.path.join(p, 'lib', '{PACKAGE}', f), os.X_OK)))"
    )
    proc = _in_workspace(ws, env, f"{sys.executable} -c \"{code}\"")
    assert proc.returncode == 0, proc.stderr
    prefix, share, executables = proc.stdout.splitlines()
    assert Path(prefix) == ws / "install" / PACKAGE
    assert Path(share) == ws / "install" / PACKAGE / "share" / PACKAGE
    assert set(EXECUTABLES) <= set(eval(executables))  # noqa: S307 - a list literal printed above


def test_a_wheel_carries_no_ros_executables(tmp_path):
    """pip builds wheels: its commands are pyproject.toml's alone (no ``node`` to shadow Node.js on a PATH)."""
    pkg = _copy_sources(tmp_path)
    proc = subprocess.run([sys.executable, "setup.py", "-q", "bdist_wheel", "-d", str(tmp_path / "dist")],
                          cwd=pkg, env=_clean_env(tmp_path), capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    (wheel,) = (tmp_path / "dist").glob("*.whl")
    with zipfile.ZipFile(wheel) as z:
        names = z.namelist()
        entry_points = next(z.read(n).decode() for n in names if n.endswith("entry_points.txt"))
    assert not [n for n in names if "/scripts/" in n or n.endswith(("/node", "/source"))], names
    scripts = {line.split("=")[0].strip() for line in entry_points.splitlines() if "=" in line}
    assert scripts == {"belt-drive", "msg-tools"}, entry_points


def test_a_symlink_install_builds_and_runs_as_ros_developers_build(tmp_path):
    """``colcon build --symlink-install`` (what most ROS 2 workspaces use) failed: colcon runs ``setup.py develop``
    in its build folder, where it links no pyproject.toml, and setuptools refused 'Multiple top-level packages
    discovered in a flat-layout'; ``develop`` wrote no ``node`` or ``source`` either. Built so, the executables
    run, the launch and config files are installed and the package is imported from its sources."""
    ws, env, log = _build(tmp_path, "--symlink-install")
    assert "Finished <<< belt_drive_ros" in log
    prefix = ws / "install" / PACKAGE
    for path in ("launch/belt_drive.launch.py", "config/belt_drive.yaml", "package.xml"):
        assert (prefix / "share" / PACKAGE / path).is_file(), path
    assert (prefix / "share" / "ament_index" / "resource_index" / "packages" / PACKAGE).is_file()
    for name, command in EXECUTABLES.items():
        proc = _in_workspace(ws, env, f"{_lib(ws)}/{name} --help")
        assert proc.returncode == 0, proc.stderr
        assert proc.stdout.startswith(f"usage: {command}"), proc.stdout[:200]
    proc = _in_workspace(ws, env, f"{sys.executable} -c 'import belt_drive_ros; print(belt_drive_ros.__file__)'")
    imported = Path(proc.stdout.strip())
    assert imported.resolve() == (ws / "src" / PACKAGE / PACKAGE / "__init__.py").resolve(), proc.stdout + proc.stderr
