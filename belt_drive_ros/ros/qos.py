"""Quality of service of every topic the package's nodes publish or subscribe.

One place, so the node, the source node, the harness and the README agree.
"""

from __future__ import annotations

from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

__all__ = ["CLOCK_QOS", "INPUT_QOS", "OUTPUT_QOS"]

#: drive_torque: only the latest message matters (zero-order hold); depth 1
#: bounds memory and latency under any burst.
INPUT_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE)
#: state outputs: reliable, a short queue for slow subscribers.
OUTPUT_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.RELIABLE)
CLOCK_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.RELIABLE)
