"""Plants that carry what a model lacks: the evaluation data of the discrepancy workflow (its tests and `make bench`).

A plant is the config with 40 % of `fdi eval`'s model mismatch drawn for a seed, sensor noise, and (maybe) physical
effects the model under test does not have, each in a form of its own (names.EFFECT_FORMS).
"""

from __future__ import annotations

from pathlib import Path

from hydro_ros.bags.writer import ContractBagWriter
from hydro_ros.contract.machine import Machine
from hydro_ros.sim.scenario import Scenario, run_blocks
from hydro_ros.studies.fdi_evaluation import mismatched_config

PLANT_MISMATCH = 0.4  # of `fdi eval`'s model mismatch
SEED = 3


def hidden_effect_plant(config: Machine, effect: str | None = None, value: float = 0.0, seed: int = SEED,
                        forms: dict[str, str] | None = None, also: dict[str, float] | None = None) -> Machine:
    """The plant's config: the mismatch drawn for ``seed`` and ``effect`` at ``value``, the effects ``also`` holds, in
    ``forms`` where given."""
    effects = ({effect: value} if effect else {}) | (also or {})
    return mismatched_config(config, seed, PLANT_MISMATCH).with_overrides({"effects": effects, "effect_forms": forms or {}})


def hidden_effect_bag(config: Machine, path: Path, effect: str | None = None, value: float = 0.0, seed: int = SEED,
                      duration: float = 40.0, forms: dict[str, str] | None = None, also: dict[str, float] | None = None) -> Path:
    """A contract bag of that plant under the simulated operator, its pressures noisy."""
    plant = hidden_effect_plant(config, effect, value, seed, forms, also)
    actuator = config.first
    with ContractBagWriter(path, actuators={actuator.name: actuator.joint}, pressure_variance=1e10) as writer:
        for _, _, block in run_blocks(plant, Scenario(duration, [], seed=seed)):
            writer.write_block(actuator.name, block)
    return path
