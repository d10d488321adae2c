"""Recording to rosbag2-compatible MCAP bags from CDR bytes (no rclpy, no *_msgs imports)."""
from clusterfem_ros.recording.recover import RecoveryReport, recover_bag
from clusterfem_ros.recording.rosbag2_mcap import Rosbag2McapWriter, default_bag_path

__all__ = ["Rosbag2McapWriter", "default_bag_path", "recover_bag", "RecoveryReport"]
