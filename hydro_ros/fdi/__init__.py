"""Fault detection and isolation (no ROS): P-II/P-III UKF and P-IV-style parity residual generators behind
one interface, thresholds, isolation, and the offline analysis of a bag."""

from hydro_ros.fdi.monitor import ERROR, OK, STALE, WARN, FdiMonitor, crossing_code, crossing_episodes
from hydro_ros.fdi.offline import FdiRun, analyse_bag, prepare, run_monitor
from hydro_ros.fdi.residuals import GENERATORS, ResidualGenerator
from hydro_ros.fdi.settings import FdiSettings

__all__ = ["ERROR", "GENERATORS", "OK", "STALE", "WARN", "FdiMonitor", "FdiRun", "FdiSettings", "ResidualGenerator",
           "analyse_bag", "crossing_code", "crossing_episodes", "prepare", "run_monitor"]
