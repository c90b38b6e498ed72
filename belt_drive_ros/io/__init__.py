"""ROS-free input and output: MCAP recordings of results, torque bags, reference bags, plots."""
