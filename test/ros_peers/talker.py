"""Peer process: publishes the sample messages every 50 ms until it is terminated (or 30 s pass)."""

import rclpy
from rclpy.node import Node
from sample_messages import force_distribution, image_bundle

from tactile_msgs.msg import ForceDistribution, ImageBundle


def main() -> None:
    rclpy.init()
    node = Node("roundtrip_talker")
    forces_pub = node.create_publisher(ForceDistribution, "/tactile/force_distribution", 10)
    bundle_pub = node.create_publisher(ImageBundle, "/tactile/image_bundle", 10)
    forces, bundle = force_distribution(), image_bundle()

    def publish() -> None:
        forces_pub.publish(forces)
        bundle_pub.publish(bundle)

    node.create_timer(0.05, publish)
    deadline = node.get_clock().now().nanoseconds + 30 * 10**9
    try:
        while rclpy.ok() and node.get_clock().now().nanoseconds < deadline:
            rclpy.spin_once(node, timeout_sec=0.1)
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    main()
