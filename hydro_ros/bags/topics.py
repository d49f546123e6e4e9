"""Topic names and types of the interface contract (section 1), in one place."""

from __future__ import annotations

JOINT_STATES = "/joint_states"
SUPPLY_PRESSURE = "/hydraulics/supply_pressure"
VALVE_COMMANDS = "/hydraulics/valve_commands"
DIAGNOSTICS = "/diagnostics"
CLOCK = "/clock"

JOINT_STATE_TYPE = "sensor_msgs/msg/JointState"
FLUID_PRESSURE_TYPE = "sensor_msgs/msg/FluidPressure"
TRUTH_KEY = "hydro_ros.truth"


def pressure_a(actuator: str) -> str:
    return f"/hydraulics/{actuator}/pressure_a"


def pressure_b(actuator: str) -> str:
    return f"/hydraulics/{actuator}/pressure_b"


def sensor_topics(actuators: list[str]) -> dict[str, str]:
    """Every measured topic of a proportional-valve machine and its type."""
    topics = {JOINT_STATES: JOINT_STATE_TYPE, SUPPLY_PRESSURE: FLUID_PRESSURE_TYPE, VALVE_COMMANDS: JOINT_STATE_TYPE}
    for actuator in actuators:
        topics[pressure_a(actuator)] = FLUID_PRESSURE_TYPE
        topics[pressure_b(actuator)] = FLUID_PRESSURE_TYPE
    return topics
