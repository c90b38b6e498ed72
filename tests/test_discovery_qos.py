"""Discovery settings and QoS of the node, in a child process each.

* A user's ``ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET`` survives importing and
  starting the node, ``ROS_LOCALHOST_ONLY`` stays unset, and rcl prints no
  deprecation or "localhost_only" warning. DDS never leaves this machine in
  that test: Fast DDS runs with its shared-memory transport only
  (``FASTDDS_BUILTIN_TRANSPORTS=SHM``), and the child checks that it opened
  no UDP socket outside loopback.
* A best-effort (sensor-data QoS) torque publisher drives the node, and a
  reliable, a best-effort and a late-joining transient-local subscriber all
  receive its outputs.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

import pytest

from belt_drive_ros.ros import environment as ros_env

pytestmark = pytest.mark.ros

CHILD = textwrap.dedent(
    r'''
    import json, os, sys, time
    before = {k: os.environ.get(k) for k in ("ROS_AUTOMATIC_DISCOVERY_RANGE", "ROS_LOCALHOST_ONLY")}
    import rclpy
    from rclpy.context import Context
    from rclpy.node import Node
    from rclpy.qos import (DurabilityPolicy, QoSProfile, ReliabilityPolicy, HistoryPolicy,
                           qos_profile_sensor_data)
    from std_msgs.msg import Float64
    import belt_drive_ros.ros.node as node_module
    after_import = {k: os.environ.get(k) for k in before}
    torque = float(sys.argv[1])
    ctx = Context()
    rclpy.init(context=ctx, domain_id=int(os.environ["ROS_DOMAIN_ID"]))
    drive = node_module.BeltDriveNode(scene="paper", context=ctx)
    probe = Node("probe", context=ctx)
    pub = probe.create_publisher(Float64, "drive_torque", qos_profile_sensor_data)
    got = {"reliable": [], "best_effort": [], "transient_local": []}
    profiles = {
        "reliable": QoSProfile(depth=10),
        "best_effort": qos_profile_sensor_data,
        "transient_local": QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
                                      reliability=ReliabilityPolicy.RELIABLE,
                                      durability=DurabilityPolicy.TRANSIENT_LOCAL),
    }
    subs = [probe.create_subscription(Float64, "shaft_speed",
                                      (lambda m, k=k: got[k].append(m.data)), profiles[k])
            for k in ("reliable", "best_effort")]
    ex = node_module.make_executor(ctx, "single")
    ex.add_node(drive); ex.add_node(probe)
    t_end = time.monotonic() + 1.5
    late = None
    while time.monotonic() < t_end:
        pub.publish(Float64(data=torque))
        ex.spin_once(timeout_sec=0.01)
        if late is None and time.monotonic() > t_end - 0.5:
            late = probe.create_subscription(Float64, "shaft_speed",
                                             lambda m: got["transient_local"].append(m.data),
                                             profiles["transient_local"])
    for _ in range(50):
        ex.spin_once(timeout_sec=0.01)
    def udp_sockets():
        inodes = set()
        for fd in os.listdir("/proc/self/fd"):
            try:
                target = os.readlink(f"/proc/self/fd/{fd}")
            except OSError:
                continue
            if target.startswith("socket:["):
                inodes.add(target[8:-1])
        local = []
        for table in ("/proc/self/net/udp", "/proc/self/net/udp6"):
            with open(table) as f:
                next(f)
                for line in f:
                    cols = line.split()
                    if cols[9] in inodes:
                        local.append(cols[1])
        return local
    result = {
        "before": before, "after_import": after_import,
        "after_start": {k: os.environ.get(k) for k in before},
        "received": {k: len(v) for k, v in got.items()},
        "speed_last": got["reliable"][-1] if got["reliable"] else None,
        "udp": udp_sockets(),
        "input_publishers": drive.count_publishers("drive_torque"),
    }
    ex.shutdown(); drive.destroy_node(); probe.destroy_node(); rclpy.shutdown(context=ctx)
    print("RESULT " + json.dumps(result))
    '''
)


def run_child(env: dict, torque: float) -> tuple[dict, str]:
    proc = subprocess.run([sys.executable, "-c", CHILD, str(torque)], env=env, capture_output=True,
                          text=True, timeout=120)
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT ")]
    assert proc.returncode == 0 and lines, f"child failed ({proc.returncode}):\n{proc.stderr[-3000:]}"
    return json.loads(lines[-1][len("RESULT "):]), proc.stderr


def _loopback_address(hex_address: str) -> bool:
    """True for 127.x.x.x (IPv4, little-endian hex) and ::1 / ::ffff:127.x (IPv6)."""
    host = hex_address.split(":")[0]
    if len(host) == 8:
        return host.endswith("7F")
    return host in ("00000000000000000000000001000000",) or (
        host.startswith("0000000000000000FFFF0000") and host.endswith("7F"))


def test_user_subnet_range_survives_node_import_and_start(ros_domain_id):
    env = ros_env.child_environment(ros_env.process_domain_id(offset=61), udp_only=False)
    env.pop("ROS_LOCALHOST_ONLY", None)
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "SUBNET"
    env["FASTDDS_BUILTIN_TRANSPORTS"] = "SHM"  # nothing on any network interface
    result, stderr = run_child(env, 5.0)
    for stage in ("before", "after_import", "after_start"):
        assert result[stage] == {"ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET", "ROS_LOCALHOST_ONLY": None}, stage
    assert "localhost_only" not in stderr.lower(), stderr
    assert "deprecat" not in stderr.lower(), stderr
    assert all(_loopback_address(a) for a in result["udp"]), result["udp"]
    assert result["received"]["reliable"] > 10, result  # the node ran and published


def test_best_effort_publisher_drives_node_and_every_subscriber_profile_connects(ros_domain_id):
    env = ros_env.child_environment(ros_env.process_domain_id(offset=63))
    assert env["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST" or env.get("ROS_LOCALHOST_ONLY")
    result, stderr = run_child(env, 10.0)
    assert result["input_publishers"] == 1
    # 10 N m for ~1.5 s on the paper scene spins the drive up; at rest it would stay at 0 rad/s
    assert result["speed_last"] is not None and result["speed_last"] > 1.0, result
    received = result["received"]
    assert received["reliable"] > 10 and received["best_effort"] > 10, received
    # the transient-local subscriber joined 0.5 s before the end: it gets the history
    # at once plus what follows
    assert received["transient_local"] > 10, received
    assert "deprecat" not in stderr.lower(), stderr
