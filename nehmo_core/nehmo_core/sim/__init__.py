"""Simulation: scenario generation and (later) kinematic stepping of a cell."""
