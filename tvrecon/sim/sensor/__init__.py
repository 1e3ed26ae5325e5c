"""The sensor pad and what it outputs: the pad (:mod:`.elastic_pad`), real sensors as presets (:mod:`.presets`), the
contact patch in world coordinates (:mod:`.patch`), the per-taxel force field (:mod:`.forces`), marker images
(:mod:`.markers`), GelSight-style RGB (:mod:`.photometric`) and the deformed pad's surface (:mod:`.surface`)."""

from tvrecon.sim.sensor.elastic_pad import SensorConfig, alpha_profile, pad_lattice, sensor_frame
from tvrecon.sim.sensor.patch import ContactPatch, contact_patch
from tvrecon.sim.sensor.presets import SENSOR_PRESETS, sensor_config

__all__ = [
    "SENSOR_PRESETS",
    "ContactPatch",
    "SensorConfig",
    "alpha_profile",
    "contact_patch",
    "pad_lattice",
    "sensor_config",
    "sensor_frame",
]
