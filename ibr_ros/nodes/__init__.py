"""Thin rclpy nodes: convert messages with msg_utils, call ibr_ros.core, publish."""
