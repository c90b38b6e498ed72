"""Drive a belt-drive node from a test script, without launch files.

The public home of :class:`BeltDriveHarness` (implemented in
:mod:`belt_drive_ros.ros.harness`)::

    from belt_drive_ros.testing import BeltDriveHarness
"""

from .ros.harness import BeltDriveHarness

__all__ = ["BeltDriveHarness"]
