"""Energy-optimal redundancy resolution (no ROS): paths, costs, the fast DP and its baselines, the
trajectory database with its catalog build, and serving a stored plan from the actual joints."""

from hydro_ros.planning.costs import Cost
from hydro_ros.planning.database import TrajectoryDatabase
from hydro_ros.planning.problem import CONTRACT_METHODS, METHODS, Plan, Problem, method_record, run_method
from hydro_ros.planning.serving import JointStateSample, ServeError, TrajectoryService, executable_trajectory
from hydro_ros.planning.trajectory import JointTrajectoryData

__all__ = ["CONTRACT_METHODS", "METHODS", "Cost", "JointStateSample", "JointTrajectoryData", "Plan", "Problem", "ServeError",
           "TrajectoryDatabase", "TrajectoryService", "executable_trajectory", "method_record", "run_method"]
