"""ROS 2 shells around `nehmo_core`: the per-arm planner node, the MCAP recorder and orchestration.

The nodes stay thin: everything testable without a middleware lives in `nehmo_core`.
"""
