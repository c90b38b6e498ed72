"""Benchmarks behind ``belt-drive bench`` and ``docs/performance.md``.

Studies (each a module with ``run(out_dir, quick=False, quiet=False)``
writing a CSV and a PNG):

* :mod:`.workprecision` -- error against CPU time for every integrator and scene;
* :mod:`.stability_map` -- where the explicit methods diverge, measured against
  the stability guard's prediction;
* :mod:`.fidelity_chart` -- rigid against flexible model error against the
  excitation frequency and the belt stiffness, with the ``auto`` switch;
* :mod:`.versus_scipy` -- the default method against ``solve_ivp`` RK45 at
  matched accuracy, and x real time per scene and method;
* :mod:`.slip_chart` -- the slipping belt: event-driven hybrid against
  step-end mode switching and regularised friction at several v_eps;
* ``node`` (written with the ROS node) -- the node's real-time figures.

Shared definitions (error metric, references, timing) are in :mod:`.common`.
Nothing here imports rclpy.
"""

STUDIES = ("workprecision", "stability", "fidelity", "versus", "slip")
