"""Forward kinematics, arm-arm signed distance (exact and learned), collision checks."""
