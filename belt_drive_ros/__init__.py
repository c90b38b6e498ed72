"""belt_drive_ros: vehicle accessory belt drive simulated as a ROS 2 node.

Three layers, one folder each:

* :mod:`belt_drive_ros.core`: parameters, model, torque sources, integrators,
  the stepper, stability, scenes, model choice, simulation (numpy, scipy and
  PyYAML only);
* :mod:`belt_drive_ros.io`: ROS-free input and output (MCAP recordings of
  results, torque bags, reference bags, plots);
* :mod:`belt_drive_ros.ros`: the rclpy adapters (node, source node, recorder,
  live replay, harness, environment).

``commands`` holds the CLI verbs, ``benchmarks`` the charts;
``tests/test_layers.py`` enforces the import rules.
"""

__version__ = "0.1.0"
