"""Peer process: waits for one message of each type and prints both, field by field, as one JSON line."""

import json
import sys

import rclpy
from rclpy.node import Node
from sample_messages import to_plain

from tactile_msgs.msg import ForceDistribution, ImageBundle


def main() -> int:
    rclpy.init()
    node = Node("roundtrip_listener")
    received = {}
    node.create_subscription(ForceDistribution, "/tactile/force_distribution",
                             lambda m: received.setdefault("force_distribution", to_plain(m)), 10)
    node.create_subscription(ImageBundle, "/tactile/image_bundle",
                             lambda m: received.setdefault("image_bundle", to_plain(m)), 10)
    deadline = node.get_clock().now().nanoseconds + 30 * 10**9
    while len(received) < 2 and node.get_clock().now().nanoseconds < deadline:
        rclpy.spin_once(node, timeout_sec=0.1)
    node.destroy_node()
    rclpy.try_shutdown()
    print(json.dumps(received))
    return 0 if len(received) == 2 else 1


if __name__ == "__main__":
    sys.exit(main())
