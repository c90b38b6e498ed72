"""msg_tools: ROS-free reading, writing and comparison of ROS 2 MCAP recordings."""
