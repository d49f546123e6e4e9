"""CAN bus of the machine: DBC codec with counter/checksum checks, log conversion (no ROS)."""
