"""Physical models (no ROS): the SAM's valve-controlled cylinder and the crane's kinematics and hydraulics."""

from hydro_ros.models.crane import Crane, Motion, load_crane
from hydro_ros.models.sam import SamModel, SamPlant, SimulationDiverged

__all__ = ["Crane", "Motion", "SamModel", "SamPlant", "SimulationDiverged", "load_crane"]
