"""The ROS 2 adapters: node, parameters, timing, diagnostics, recorder, live replay, source node, harness."""
