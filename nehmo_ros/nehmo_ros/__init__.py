"""ROS 2 (rclpy) shells around `nehmo_core`: the per-arm planner, the bag recorder, orchestration.

The nodes stay thin: everything testable without a middleware lives in `nehmo_core`.
"""
