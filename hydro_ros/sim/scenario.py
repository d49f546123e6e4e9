"""Offline scenarios: the plant, its operator and its sensors run for a duration, block by block."""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from hydro_ros.contract.errors import InputError
from hydro_ros.contract.machine import Machine
from hydro_ros.contract.names import Injection
from hydro_ros.contract.samples import PER_ACTUATOR, Samples
from hydro_ros.models.sam import SamModel, SamPlant
from hydro_ros.models.serial_arm import SerialArm
from hydro_ros.sim.blocks import in_blocks, replace_injection
from hydro_ros.sim.excitation import OperatorReference
from hydro_ros.sim.sensors import SensorModel


@dataclass
class Scenario:
    duration_s: float
    injections: Sequence[Injection] = ()
    seed: int = 0
    actuator: str | None = None  # None: the machine's first actuator

    def truth(self, machine: Machine) -> dict[str, Any]:
        """Ground truth stored in the bag's custom_data (docs/interface.md section 2)."""
        return {
            "machine": machine.name,
            "config": machine.source.name,
            "actuator": self.actuator or machine.first.name,
            "seed": self.seed,
            "duration_s": self.duration_s,
            "faults": [
                {"name": i.name, "value": i.value, "onset_s": i.onset_s, "ramp_s": i.ramp_s} for i in self.injections
            ],
        }


@dataclass
class ScenarioRun:
    """Live objects of one scenario, for callers that step it themselves (plant_sim)."""

    plant: SamPlant
    sensors: SensorModel
    operator: OperatorReference

    def step(self, n: int, commands: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, Samples]:
        """Advance ``n`` samples; with ``commands`` None the simulated operator drives."""
        if commands is None:
            times, states, applied = self.plant.advance(n, references=self.operator.next(n))
        else:
            times, states, applied = self.plant.advance(n, commands=commands)
        return times, states, self.sensors.measure(times, states, applied)


def start(machine: Machine, scenario: Scenario) -> ScenarioRun:
    rng = np.random.default_rng(scenario.seed)
    model = SamModel(machine, scenario.actuator)
    excitation = machine.excitation
    plant = SamPlant(model, injections=scenario.injections, operator_gain=excitation.gain, max_command=excitation.max_command)
    operator = OperatorReference(
        excitation,
        rng,
        start=float(model.joint_from_piston(plant.state[4])[0]),
        sample_rate=model.sample_rate,
    )
    return ScenarioRun(plant, SensorModel(model, rng, scenario.injections), operator)


def run_blocks(
    machine: Machine, scenario: Scenario, progress: Callable[[int], None] | None = None
) -> Iterator[tuple[np.ndarray, np.ndarray, Samples]]:
    """Yield (times, true states, measurements) per block until ``duration_s``."""
    run = start(machine, scenario)
    yield from in_blocks(int(round(scenario.duration_s * run.plant.model.sample_rate)), run.step, progress)


def simulate(machine: Machine, scenario: Scenario) -> Samples:
    """The whole scenario's measurements as one actuator's (n, 1) columns (the monitor's layout)."""
    parts = [measured for _, _, measured in run_blocks(machine, scenario)]
    return Samples(**{f.name: None if getattr(parts[0], f.name) is None else np.concatenate([getattr(p, f.name) for p in parts])
                      for f in fields(Samples)}).as_columns()


class MachineRun:
    """Every actuator of a machine config stepped together into one block of (n, A) columns.

    A machine with an ``arm:`` moves its links together (``sim.arm_cylinders``: one arm's rigid-body dynamics,
    a payload at its tip; ``payload_mass`` injected on any actuator hangs there). Without one, each actuator is a
    boom of its own: its cylinder, valve and configured ``load``, its operator and sensors, and actuator i draws
    its noise from ``seed + i``, so the first keeps a one-actuator machine's seed.
    """

    def __init__(self, machine: Machine, injections: Mapping[str, Sequence[Injection]], seed: int = 0) -> None:
        from hydro_ros.sim.arm_cylinders import ArmCylinders, ArmRun  # the one-boom machines need not compile it

        unknown = sorted(set(injections) - set(machine.actuator_names))
        if unknown:
            raise InputError(f"fault or effect on {', '.join(unknown)}: no such actuator (actuators: {', '.join(machine.actuator_names)})")
        self.actuators = machine.actuator_names
        self.sample_rate = machine.sample_rate_hz
        self.runs: list[ScenarioRun] = []
        self.arm = None
        if machine.arm is not None:
            faults = {name: [i for i in found if i.name != "payload_mass"] for name, found in injections.items()}
            payload = [i for found in injections.values() for i in found if i.name == "payload_mass"]
            self.arm = ArmCylinders(machine, SerialArm.of(machine), ArmRun(math.inf, seed, faults, payload))
        else:
            self.runs = [start(machine, Scenario(math.inf, tuple(injections.get(name, ())), seed=seed + i, actuator=name))
                         for i, name in enumerate(self.actuators)]

    @property
    def sample_index(self) -> int:
        return self.arm.sample_index if self.arm is not None else self.runs[0].plant.sample_index

    @property
    def time(self) -> float:
        return self.sample_index / self.sample_rate

    def advance(self, n: int, commands: np.ndarray | None = None) -> tuple[list[np.ndarray], Samples]:
        """``n`` samples of every actuator: each one's true states and the measurements as (n, A) columns; ``commands``
        (n, A) valve commands, None: the simulated operators drive."""
        if self.arm is not None:
            states, measured = self.arm.step(n, commands)
            return [states[:, i] for i in range(len(self.actuators))], measured
        steps = [run.step(n, None if commands is None else commands[:, i]) for i, run in enumerate(self.runs)]
        parts = [measured for _, _, measured in steps]
        first = parts[0]
        return [states for _, states, _ in steps], Samples(**{
            f.name: (None if getattr(first, f.name) is None else
                     np.column_stack([getattr(p, f.name) for p in parts]) if f.name in PER_ACTUATOR else getattr(first, f.name))
            for f in fields(Samples)})

    def step(self, n: int, commands: np.ndarray | None = None) -> Samples:
        return self.advance(n, commands)[1]

    def set_fault(self, actuator: str, name: str, value: float, now_s: float) -> None:
        """``name`` of size ``value`` (0: none) in ``actuator``'s cylinder from ``now_s`` on, replacing its previous size (on an
        arm, ``ArmCylinders.set_fault``: a payload at the tip)."""
        if self.arm is not None:
            self.arm.set_fault(actuator, name, value, now_s)
            return
        run = self.runs[self.actuators.index(actuator)]
        for holder in (run.plant.injections, run.sensors.injections):
            replace_injection(holder, name, value, now_s)

    def active_faults(self) -> list[str]:
        """``actuator:name=value`` of every fault set (on an arm, ``payload_mass=value`` at the tip)."""
        if self.arm is not None:
            return self.arm.active_faults()
        return sorted({f"{actuator}:{i.name}={i.value:g}" for actuator, run in zip(self.actuators, self.runs)
                       for i in run.plant.injections + run.sensors.injections})

    def blocks(self, duration_s: float, progress: Callable[[int], None] | None = None) -> Iterator[tuple[list[np.ndarray], Samples]]:
        """(true states per actuator, measurements) per block until ``duration_s``."""
        yield from in_blocks(int(round(duration_s * self.sample_rate)), self.advance, progress)


def simulate_machine(machine: Machine, duration_s: float, injections: Mapping[str, Sequence[Injection]] | None = None,
                     seed: int = 0) -> Samples:
    """Every actuator's measurements over ``duration_s`` as (n, A) columns (the monitor's layout)."""
    parts = [measured for _, measured in MachineRun(machine, injections or {}, seed).blocks(duration_s)]
    return Samples(**{f.name: None if getattr(parts[0], f.name) is None else np.concatenate([getattr(p, f.name) for p in parts])
                      for f in fields(Samples)})
