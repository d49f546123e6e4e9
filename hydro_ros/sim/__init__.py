"""Simulation of a monitored machine: sensors, operator excitation and scenarios (no ROS)."""
