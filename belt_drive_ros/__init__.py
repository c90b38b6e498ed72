"""belt_drive_ros: vehicle accessory belt drive simulated as a ROS 2 node.

The numerical core (``params``, ``model``, ``sources``, ``integrators``,
``stability``, ``scene``, ``simulate``, ``fidelity``) imports numpy, scipy and
PyYAML only. rclpy is imported by ``node``, ``source_node``, ``testing`` and
``recording`` alone; mcap by ``msg_tools`` and ``recording``.
"""

__version__ = "0.1.0"
