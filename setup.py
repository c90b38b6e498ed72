"""The ROS 2 (ament_python) side of the package, for colcon.

Everything pip needs is in pyproject.toml; pip and ``make install`` work as
without this file. colcon builds ament_python packages by running
``setup.py install``: for that build this file adds

* the files a ROS 2 package installs besides its Python code (``data_files``):
  the ament index marker, ``package.xml``, the launch and parameter files;
* the executables ``ros2 run`` and launch files look for in
  ``lib/belt_drive_ros/`` (setup.cfg sends scripts there): ``node`` is
  ``belt-drive node``, ``source`` is ``belt-drive source``, written for the
  Python that runs the build, as setuptools writes console scripts. They are
  written only into a ``lib/belt_drive_ros`` scripts folder, never into a
  wheel, so ``pip install`` puts no ``node`` (Node.js's name) on a PATH.

``colcon build --symlink-install`` runs ``setup.py develop`` instead, from
its build folder, where colcon links setup.py, setup.cfg and the packages
but not pyproject.toml: the distribution then reads the pyproject.toml
beside the real setup.py (without it setuptools refused the build:
'Multiple top-level packages discovered'), and ``develop`` writes the same
ROS executables.
"""

from glob import glob
from pathlib import Path
import sys

from setuptools import setup
from setuptools.command.develop import develop
from setuptools.command.install_scripts import install_scripts
from setuptools.dist import Distribution

PACKAGE = "belt_drive_ros"
#: the package's sources: where setup.py is, also when colcon runs it through a link from its build folder
SOURCE = Path(__file__).resolve().parent
#: executable in lib/belt_drive_ros -> belt-drive subcommand it runs
ROS_EXECUTABLES = {"node": "node", "source": "source"}

WRAPPER = '''#!{python}
# -*- coding: utf-8 -*-
# 'ros2 run {package} {name}' = 'belt-drive {command}' (written by setup.py at install)
import sys

from belt_drive_ros.cli import main

if __name__ == "__main__":
    sys.exit(main(["{command}", *sys.argv[1:]]))
'''


def write_ros_executables(target: Path, dry_run: bool) -> list:
    """The ROS executables written into ``target`` when it is ``lib/belt_drive_ros``; their paths."""
    if target.parts[-2:] != ("lib", PACKAGE):
        return []  # a wheel or a plain prefix: only pyproject.toml's commands
    paths = []
    for name, command in ROS_EXECUTABLES.items():
        path = target / name
        if not dry_run:
            path.write_text(WRAPPER.format(python=sys.executable, package=PACKAGE, name=name, command=command))
            path.chmod(0o755)
        paths.append(str(path))
    return paths


class InstallRosExecutables(install_scripts):
    """``install_scripts``, plus the ROS executables when the scripts go to ``lib/belt_drive_ros``."""

    def run(self):
        super().run()
        self.outfiles += write_ros_executables(Path(self.install_dir), self.dry_run)


class DevelopRosExecutables(develop):
    """``develop`` (``colcon build --symlink-install``), plus the ROS executables in its ``lib/belt_drive_ros``."""

    def run(self):
        super().run()
        if getattr(self, "script_dir", None) and not getattr(self, "uninstall", False):
            write_ros_executables(Path(self.script_dir), self.dry_run)


class PlainRequiresPython(Distribution):
    """pyproject.toml's ``requires-python`` kept as the string setup.py's ``python_requires`` would be.

    colcon reads a package's setup options by printing them and parsing them
    back as Python literals (colcon-python-setup-py); the specifier object
    setuptools makes from pyproject.toml does not parse back, the string does.
    Run where no pyproject.toml is (colcon's build folder with
    ``--symlink-install``), it reads the one of :data:`SOURCE`.
    """

    def parse_config_files(self, filenames=None, *args, **kwargs):
        if filenames is None and not Path("pyproject.toml").exists() and (SOURCE / "pyproject.toml").is_file():
            filenames = [*self.find_config_files(), str(SOURCE / "pyproject.toml")]
        super().parse_config_files(filenames, *args, **kwargs)
        for holder in (self, self.metadata):
            if getattr(holder, "python_requires", None) is not None:
                holder.python_requires = str(holder.python_requires)


setup(
    distclass=PlainRequiresPython,
    license="Apache-2.0",  # pyproject.toml's dynamic "license": every setuptools reads it alike (see pyproject.toml)
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + PACKAGE]),
        ("share/" + PACKAGE, ["package.xml"]),
        ("share/" + PACKAGE + "/launch", sorted(glob("launch/*.launch.py"))),
        ("share/" + PACKAGE + "/config", sorted(glob("config/*.yaml"))),
    ],
    cmdclass={"install_scripts": InstallRosExecutables, "develop": DevelopRosExecutables},
)
