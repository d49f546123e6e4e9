"""Topic names and types of the interface contract (docs/interface.md section 1), in one place."""

from __future__ import annotations

JOINT_STATES = "/joint_states"
SUPPLY_PRESSURE = "/hydraulics/supply_pressure"
VALVE_COMMANDS = "/hydraulics/valve_commands"
DIAGNOSTICS = "/diagnostics"
CLOCK = "/clock"
FDI_HALT = "/fdi/halt"
FDI_RESIDUALS = "/fdi/residuals"
FDI_STATUS_PREFIX = "hydro_ros/fdi/"  # + actuator: one DiagnosticStatus per monitored actuator
SENSOR_STATUS_PREFIX = "hydro_ros/sensors/"  # + actuator: the health of its readings (fdi_node)
FDI_HALT_STATUS = "hydro_ros/fdi_halt"  # the halt decision and its reason, machine-wide (values: halt, kind clear/hold/fault)

JOINT_STATE_TYPE = "sensor_msgs/msg/JointState"
FLUID_PRESSURE_TYPE = "sensor_msgs/msg/FluidPressure"
TRUTH_KEY = "hydro_ros.truth"
# sensor streams are reliable with a deep queue, so a replay of a 1 kHz bag loses nothing
SENSOR_QUEUE_DEPTH = 1000


def pressure_a(actuator: str) -> str:
    return f"/hydraulics/{actuator}/pressure_a"


def pressure_b(actuator: str) -> str:
    return f"/hydraulics/{actuator}/pressure_b"


LS_PRESSURE = "/hydraulics/ls_pressure"
# Extension of the contract: every measured column of a machine, many samples per message (a PointCloud2 used as a
# table: one point per sample, fields "t" [s after header.stamp] then "<joint or actuator>/<quantity>" and
# "supply_pressure"). At 1 kHz a crane's 19 per-sample topics are ~19 000 messages a second, more than rclpy carries
# in one process; the same samples in blocks of 10 ms are 100 (docs/crane_monitoring.md).
SAMPLE_BLOCK = "/hydraulics/sample_block"
POINT_CLOUD2_TYPE = "sensor_msgs/msg/PointCloud2"
MOBILE_VALVE_PRESSURES = ("pilot_pressure_1", "pilot_pressure_2", "compensator_pressure")


def actuator_pressure(actuator: str, quantity: str) -> str:
    """/hydraulics/<actuator>/<quantity> for pressure_a/b and the mobile-valve pressures."""
    return f"/hydraulics/{actuator}/{quantity}"


def sensor_topics(actuators: list[str], *, mobile: bool = False) -> dict[str, str]:
    """Every measured topic of a machine and its type; mobile valves add pilot/compensator/LS."""
    topics = {JOINT_STATES: JOINT_STATE_TYPE, SUPPLY_PRESSURE: FLUID_PRESSURE_TYPE, VALVE_COMMANDS: JOINT_STATE_TYPE}
    for actuator in actuators:
        topics[pressure_a(actuator)] = FLUID_PRESSURE_TYPE
        topics[pressure_b(actuator)] = FLUID_PRESSURE_TYPE
        if mobile:
            for quantity in MOBILE_VALVE_PRESSURES:
                topics[actuator_pressure(actuator, quantity)] = FLUID_PRESSURE_TYPE
    if mobile:
        topics[LS_PRESSURE] = FLUID_PRESSURE_TYPE
    return topics


def fdi_residual_channels(actuators: list[str], *, mobile: bool = False) -> list[str]:
    """The `name` layout of /fdi/residuals: per actuator and chamber, the filtered residual then its threshold.

    UKF residuals are chamber pressures (``p``, MPa); parity residuals on mobile valves are chamber
    flows (``Q``, L/min). The Foxglove layout and the HMI index the message by this layout.
    """
    quantity = "Q" if mobile else "p"
    return [f"{actuator}/{kind}_{quantity}{chamber}" for actuator in actuators for chamber in "AB" for kind in ("mean_r", "threshold")]
