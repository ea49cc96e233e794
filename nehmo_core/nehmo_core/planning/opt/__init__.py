"""The paper's problem Opt: the problem, the planner interface and the planner's settings."""
