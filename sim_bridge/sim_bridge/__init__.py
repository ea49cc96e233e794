"""ROS 2 bridge to the PyBullet simulation of `nehmo_core`: joint states, `/clock`, commands."""
