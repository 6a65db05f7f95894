"""rosbag2 (MCAP) bags of the tactile stack without rosbag2: record, replay, evaluate offline (`tactile-bag`).

    bagfile     write and read bags with the pure-Python `rosbags` (files that `ros2 bag` opens)
    message_types  type names -> rosbags type store and rclpy message classes
    topics      the stack's topics, their types and QoS
    record, play   the ROS side (rclpy nodes)
    evaluate    offline evaluation of a bag against its recorded ground truth (no DDS)
    mcap_crcs   the MCAP file's CRCs, which the rosbags writer leaves 0, filled in and checked
    cli         the `tactile-bag` command

docs/bags.md describes the commands.
"""
