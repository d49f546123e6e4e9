"""Simulation of a monitored machine: sensors, operator excitation, scenarios and the closed-loop crane (no ROS)."""
