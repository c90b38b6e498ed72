"""belt_drive_ros: vehicle accessory belt drive simulated as a ROS 2 node.

Three layers, one folder each:

* :mod:`belt_drive_ros.core`: parameters, model, torque sources, integrators,
  the stepper, stability, scenes, model choice, simulation (numpy, scipy and
  numba only; it reads no file);
* :mod:`belt_drive_ros.io`: ROS-free input and output (scene and YAML files,
  MCAP recordings of results, torque bags, reference bags, plots);
* :mod:`belt_drive_ros.ros`: the rclpy adapters (node, source node, recorder,
  live replay, harness, environment).

``commands`` holds the CLI verbs, ``benchmarks`` the charts;
``tests/test_layers.py`` enforces the import rules.
"""

import os as _os

__version__ = "0.1.0"

# BLAS and LAPACK on this package's matrices (4x4 to 12x12: matrix exponentials, eigenvalues, solves) run
# fastest on one thread: OpenBLAS's worker threads cost far more than such a product, and on a busy machine
# waking them costs milliseconds per call (a 6x6 scipy.linalg.expm: 15 us on one thread, up to 30 ms with
# them on two loaded cores). Set before numpy or scipy load their OpenBLAS; a value you set yourself is kept.
_os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
