"""Quality of service of every topic the package's nodes publish or subscribe.

One place, so the node, the source node, the harness and the README agree.
A subscription matches a publisher when it asks for no more than the
publisher offers (reliable >= best effort, transient local >= volatile), so:

* the input asks for the least (best effort, volatile, keep last 1): it
  matches reliable and best-effort publishers alike (sensor-data QoS engine
  models and bridges included), and only the latest torque matters anyway
  (zero-order hold);
* the outputs offer the most (reliable, transient local, keep last 10): the
  common subscriber profiles connect -- reliable (rclpy's default),
  best-effort sensor data (``qos_profile_sensor_data``), and transient-local
  subscribers, which also get the last 10 messages at once when they join
  late (Foxglove, a monitor started after the node);
* ``robot_description`` (the drive's URDF) is latched as
  ``robot_state_publisher`` latches it: reliable, transient local, keep
  last 1, so a subscriber that joins at any time gets the current one;
* ``/tf`` (published where ``tf2_msgs`` is installed) as tf2_ros's
  ``TransformBroadcaster`` offers it: reliable, volatile, keep last 100;
* ``/clock`` (published with ``publish_clock``) is reliable keep last 10,
  volatile: rclpy's and rclcpp's own ``/clock`` subscriptions (best effort,
  keep last 1) and reliable ones match it; an old clock is never worth
  replaying to a late joiner.
"""

from __future__ import annotations

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

__all__ = ["CLOCK_QOS", "CLOCK_TICK_QOS", "DESCRIPTION_QOS", "INPUT_QOS", "OUTPUT_QOS", "TF_QOS"]

#: drive_torque (subscription): best effort, volatile, keep last 1.
INPUT_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                       reliability=ReliabilityPolicy.BEST_EFFORT,
                       durability=DurabilityPolicy.VOLATILE)
#: state outputs (publishers): reliable, transient local, keep last 10.
OUTPUT_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
                        reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.TRANSIENT_LOCAL)
#: robot_description (publisher): reliable, transient local, keep last 1 (latched).
DESCRIPTION_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                             reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
#: /clock (publisher): reliable, volatile, keep last 10.
CLOCK_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
                       reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.VOLATILE)
#: /clock (subscription that ticks the node and the torque source on simulated time): as rclpy's own time source
#: reads it, best effort, volatile, keep last 1 (matches any publisher; a late callback sees the latest time and
#: ticks once to it, as a timer fires once however far the clock jumped).
CLOCK_TICK_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                            reliability=ReliabilityPolicy.BEST_EFFORT,
                            durability=DurabilityPolicy.VOLATILE)
#: /tf (publisher): reliable, volatile, keep last 100 (tf2_ros's DynamicBroadcasterQoS).
TF_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100,
                    reliability=ReliabilityPolicy.RELIABLE,
                    durability=DurabilityPolicy.VOLATILE)
#: ``~/reset`` keeps every request of a burst (the default services QoS keeps 10): both nodes' service
RESET_QOS = QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE)
