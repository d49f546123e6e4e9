"""The package's fixed outside face (docs/interface.md): topic names, fault and effect names,
sample and trajectory types, the typed machine config, and the one error family for bad input."""

from hydro_ros.contract.config import ConfigError, config_dir, default_config_path, read_config, with_overrides
from hydro_ros.contract.errors import BuildError, DatabaseError, InputError
from hydro_ros.contract.machine import Actuator, Machine, Sensors, Valve, load_machine_config
from hydro_ros.contract.names import Effect, Fault, Injection, parse_injection
from hydro_ros.contract.samples import Samples

__all__ = ["Actuator", "BuildError", "ConfigError", "DatabaseError", "Effect", "Fault", "InputError", "Injection", "Machine",
           "Samples", "Sensors", "Valve", "config_dir", "default_config_path", "load_machine_config", "parse_injection",
           "read_config", "with_overrides"]
