"""Benchmarks behind ``belt-drive bench`` and ``docs/performance.md``.

Studies (each a module with ``run(out_dir, quick=False, quiet=False)``
writing a CSV and a PNG):

* :mod:`.workprecision` -- error against CPU time for every integrator and scene
  (``truck_compressor`` on the slipping model among them);
* :mod:`.stability_map` -- where the explicit methods diverge, measured against
  the stability guard's prediction (and on the slipping scene, per friction law);
* :mod:`.fidelity_chart` -- rigid against flexible model error against the
  excitation frequency and the belt stiffness, with the ``auto`` switch, and
  the linear against the slipping model as the load passes the limit;
* :mod:`.versus_scipy` -- the default method against ``solve_ivp`` RK45 at
  matched accuracy, and x real time per scene and method;
* :mod:`.slip_chart` -- a harder stick-slip case: event-driven hybrid against
  step-end mode switching and regularised friction at several v_eps;
* ``node`` (written with the ROS node) -- the node's real-time figures.

Shared definitions (error metric, references, timing) are in :mod:`.common`;
the slipping scenes' runs in :mod:`.slip_runs`.
Nothing here imports rclpy.
"""

STUDIES = ("workprecision", "stability", "fidelity", "versus", "slip")
