"""tvrecon: EIP tactile simulation in pure torch, generated tactile-visual data and 3D reconstruction from it.

Importing the package registers the OmegaConf resolver ``sensor_preset`` with which the Hydra blocks of the real
sensors (``configs/data/sensor/digit.yaml`` ...) read their pads from :mod:`tvrecon.sim.sensor.presets`:
``${sensor_preset:digit,resolution}`` is ``sensor_config("digit", n_grid=128).resolution``.
"""

from omegaconf import OmegaConf


def _sensor_preset(name: str, field: str, n_grid: int = 128) -> object:
    from tvrecon.sim.sensor.presets import preset_field

    return preset_field(name, field, n_grid)


if not OmegaConf.has_resolver("sensor_preset"):
    OmegaConf.register_new_resolver("sensor_preset", _sensor_preset)
