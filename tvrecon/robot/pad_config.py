"""The configuration of the EIP pad on a robot link (:class:`PadConfig`): its size, sensor, press and caching."""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["PadConfig"]


@dataclass
class PadConfig:
    """Physical pad and press settings of a tactile pad on a robot link.

    resolution: (H, W) tactile pixels; pad_size: physical width of the contact layer in metres (2 cm default).
    n_grid: MPM grid cells across the press domain (the domain spans ``n_grid * dx`` metres, dx = pad cell size).
    stiffness: N/m of the pad's elastic give (indentation = max(penetration, force / stiffness)).
    min_depth, max_depth: clamp of the indentation in metres.
    min_force: total normal force (N) below which the finger counts as not touching.
    move_tol: re-simulate when the contact point moves more than this on the object (metres).
    depth_tol: re-simulate when the indentation changes by more than this fraction.
    E, nu, layers, spacing: pad material / thickness / particle spacing (cells) passed to the EIP simulator.
    speed_fraction: hand speed of the press as a fraction of the P-wave speed (``PressConfig.speed_fraction``).
    """

    resolution: tuple[int, int] = (24, 24)
    pad_size: float = 0.02
    n_grid: int = 64
    layers: int = 4
    E: float = 3.0
    nu: float = 0.25
    stiffness: float = 2.5e4
    min_depth: float = 2.0e-4
    max_depth: float = 2.5e-3
    min_force: float = 0.05
    move_tol: float = 0.003
    depth_tol: float = 0.35
    max_steps: int = 400
    spacing: float = 0.5
    speed_fraction: float = 0.1

    def __post_init__(self) -> None:
        self.resolution = tuple(int(r) for r in self.resolution)  # type: ignore[assignment]
        if len(self.resolution) != 2 or min(self.resolution) < 2:
            raise ValueError(f"PadConfig.resolution must be (H, W) with H, W >= 2, got {self.resolution}")
        if not float(self.pad_size) > 0:
            raise ValueError(f"PadConfig.pad_size must be > 0 metres, got {self.pad_size}")
        if not 0.0 < float(self.spacing) <= 1.0:
            raise ValueError(f"PadConfig.spacing must be in (0, 1] grid cells, got {self.spacing}")

    @property
    def dx(self) -> float:
        """Grid cell size in metres (the pad spans (max(H, W) - 1) * spacing cells)."""
        return self.pad_size / ((max(self.resolution) - 1) * self.spacing)

    @property
    def domain_size(self) -> float:
        """World metres spanned by the press domain (``PressConfig.domain_size``)."""
        return self.n_grid * self.dx

    @classmethod
    def from_sensor(cls, sensor: object, pad_size: float = 0.02, **overrides: object) -> PadConfig:
        """A pad with a ``tvrecon.sim.SensorConfig``'s resolution, layers, spacing, E and nu, ``pad_size`` m wide."""
        from tvrecon.sim.sensor.elastic_pad import SensorConfig

        if not isinstance(sensor, SensorConfig):
            raise ValueError(f"from_sensor needs a tvrecon.sim.SensorConfig, got {type(sensor).__name__}")
        base = {
            "resolution": tuple(sensor.resolution),
            "layers": int(sensor.layers),
            "spacing": float(sensor.spacing),
            "E": float(sensor.E),
            "nu": float(sensor.nu),
            "pad_size": float(pad_size),
        }
        return cls(**{**base, **overrides})

    @classmethod
    def from_preset(cls, name: str, n_grid: int = 64, **overrides: object) -> PadConfig:
        """A real sensor's pad (``tvrecon.sim.sensor.presets``: "digit", "gelsight_mini", ...) on ``n_grid`` cells.

        The resolution, layers, E and nu come from :func:`~tvrecon.sim.sensor.presets.sensor_config`, the hand speed
        from its ``press_overrides``; ``pad_size`` is the span of the preset's contact layer in metres (its longer
        side less one particle spacing, the convention of :attr:`dx`), so a cell is the preset's ``cell_mm``.
        """
        from tvrecon.sim.sensor.presets import SENSOR_PRESETS, sensor_config, speed_fraction_for

        sensor = sensor_config(name, n_grid)  # raises ValueError naming the presets
        preset = SENSOR_PRESETS[name]
        cell = preset.cell_mm(n_grid) * 1e-3  # metres per cell
        base = {
            "n_grid": int(n_grid),
            "speed_fraction": round(speed_fraction_for(float(sensor.nu)), 4),
        }
        return cls.from_sensor(
            sensor, pad_size=cell * (max(sensor.resolution) - 1) * sensor.spacing, **{**base, **overrides}
        )

    @classmethod
    def coerce(cls, pad: PadConfig | object | str | None, n_grid: int = 64) -> PadConfig:
        """A :class:`PadConfig` from itself, a ``SensorConfig`` (2 cm wide), a preset name, or None (the default)."""
        if pad is None:
            return cls()
        if isinstance(pad, cls):
            return pad
        if isinstance(pad, str):
            return cls.from_preset(pad, n_grid)
        return cls.from_sensor(pad)
