"""Pure algorithms on numpy arrays: no rclpy, no message types."""
