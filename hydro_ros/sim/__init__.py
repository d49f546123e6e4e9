"""Simulation of a monitored machine: sensors, operator excitation, scenarios and the closed-loop crane (no ROS)."""

from hydro_ros.sim.closed_loop_crane import CranePlant
from hydro_ros.sim.scenario import Scenario, run_blocks, start

__all__ = ["CranePlant", "Scenario", "run_blocks", "start"]
