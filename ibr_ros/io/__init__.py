"""File formats outside ROS: photo metadata."""
