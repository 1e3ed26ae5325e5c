"""Pads with the geometry and material of common tactile sensors, from their public specs.

Their sources: ``docs/guides/sensor-outputs.md``.

The simulator has no physical units of its own: lengths are grid cells (``dx = domain_size / n_grid`` world units),
the stress unit is whatever ``E`` is measured in, the density sets the time unit. A preset fixes one unit system:

- **length**: the pad's longer side spans ``fill * n_grid`` cells (default ``fill`` 0.25, the paper's 64-particle
  pad on a 128 grid), so one cell is ``cell_mm = long side (mm) / (fill * n_grid)`` and the domain is
  ``domain_mm = n_grid * cell_mm``. A mesh in millimetres is pressed at the sensor's scale with
  ``PressConfig(domain_size=domain_mm)`` (:meth:`SensorPreset.press_overrides` gives it);
- **stress**: ``E`` in simulation units = E (kPa) / ``STRESS_UNIT_KPA`` (100 kPa: the default ``E = 3`` is 0.3 MPa);
- **density**: ``rho = 1`` is 1000 kg/m^3 (silicone 1.0-1.1 g/cm^3; presets keep the default 1);
- hence velocity unit ``sqrt(stress / density)`` = 10 m/s, time unit ``domain_mm / 10 m/s`` and force unit
  ``stress * domain_mm^2`` (:meth:`SensorPreset.force_unit_newton`).

Only ``nu`` and the geometry change the displacement images: a press drives the hand a given depth (kinematic), so
the images scale out ``E`` (it changes forces and the CFL ``dt``, not the steps per cell). The hand speed is a
fraction of the P-wave speed; what must hold is "slow against the shear wave" (quasi-static; a real press at
mm/s is ~1e-4 of it). Silicone gels have ``nu`` 0.47-0.49; explicit MLS-MPM with the fixed-corotated model gets
stiff and locks near 0.5 (``lambda / mu`` = 2 nu / (1 - 2 nu) is 49 at 0.49), so the presets simulate
``NU_SIM`` = 0.45 (``lambda / mu`` = 9) and slow the hand to keep the default's ratio to the shear-wave speed
(:func:`speed_fraction_for`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from tvrecon.sim.sensor.elastic_pad import SensorConfig

__all__ = [
    "DEFAULT_FILL",
    "NU_SIM",
    "SENSOR_PRESETS",
    "STRESS_UNIT_KPA",
    "SensorPreset",
    "pad_fits",
    "preset_field",
    "press_overrides",
    "sensor_config",
    "speed_fraction_for",
]

#: kPa per simulation stress unit (E = 3 is 0.3 MPa).
STRESS_UNIT_KPA = 100.0
#: Poisson ratio simulated for the (near-incompressible) silicone gels; the physical value is kept on the preset.
NU_SIM = 0.45
#: Fraction of ``n_grid`` spanned by the pad's longer side (0.25: 32 cells on 128, the paper's 64x64 pad).
DEFAULT_FILL = 0.25
#: The default press: hand at 0.1 of the P-wave speed with nu = 0.25 (``PressConfig.speed_fraction``).
_REF_SPEED_FRACTION, _REF_NU = 0.1, 0.25


def _shear_to_p(nu: float) -> float:
    """c_s / c_p = sqrt((1 - 2 nu) / (2 (1 - nu)))."""
    return math.sqrt((1.0 - 2.0 * nu) / (2.0 * (1.0 - nu)))


def speed_fraction_for(nu: float) -> float:
    """``PressConfig.speed_fraction`` that keeps the hand at the default's fraction of the shear-wave speed.

    The default (0.1 of the P-wave speed at nu = 0.25) is 0.17 of the shear-wave speed; at nu = 0.45 the same
    ratio needs 0.052 (twice the steps).
    """
    return _REF_SPEED_FRACTION * _shear_to_p(float(nu)) / _shear_to_p(_REF_NU)


@dataclass(frozen=True)
class SensorPreset:
    """Public specs of one sensor and the pad that stands for it.

    Attributes:
        name: preset key. title: the sensor's name.
        width_mm, height_mm: sensing area (x along the pad's W axis, y along H), mm.
        thickness_mm: elastomer thickness, mm.
        E_kPa: Young's modulus of the elastomer, kPa. nu: its Poisson ratio (physical).
        source: where each number comes from; ``approximate`` names the numbers that are not from a spec sheet.
        approximate: fields that are estimates (not in the sensor's datasheet / paper).
        note: modelling caveat (e.g. a dome stood for by a flat slab).
    """

    name: str
    title: str
    width_mm: float
    height_mm: float
    thickness_mm: float
    E_kPa: float
    nu: float
    source: str
    approximate: tuple[str, ...] = ()
    note: str = ""

    def cell_mm(self, n_grid: int, fill: float = DEFAULT_FILL) -> float:
        """Millimetres per grid cell when the longer side spans ``fill * n_grid`` cells."""
        return max(self.width_mm, self.height_mm) / (float(fill) * int(n_grid))

    def domain_mm(self, n_grid: int, fill: float = DEFAULT_FILL) -> float:
        """Millimetres spanned by the domain (``domain_size`` for meshes in mm)."""
        return int(n_grid) * self.cell_mm(n_grid, fill)

    def force_unit_newton(self, n_grid: int, fill: float = DEFAULT_FILL) -> float:
        """Newtons per simulation force unit (``TactileReading.force``): 100 kPa x (domain length)^2."""
        return STRESS_UNIT_KPA * 1e3 * (self.domain_mm(n_grid, fill) * 1e-3) ** 2

    def sensor_config(self, n_grid: int = 128, fill: float = DEFAULT_FILL, spacing: float = 0.5) -> SensorConfig:
        """The pad at ``n_grid``: resolution and layers from the mm sizes, E in 100 kPa, nu = ``NU_SIM``.

        Particles sit ``spacing`` cells apart; each covers ``spacing`` cells, so the contact layer's W particles
        cover ``W * spacing`` cells (the sensing width) and ``layers - 1`` gaps span the thickness.
        """
        if not 0.0 < float(fill) <= 0.6:
            raise ValueError(f"fill (pad side / domain) must be in (0, 0.6], got {fill}")
        step = self.cell_mm(n_grid, fill) * float(spacing)  # mm between particles
        W = max(2, round(self.width_mm / step))
        H = max(2, round(self.height_mm / step))
        layers = max(2, round(self.thickness_mm / step) + 1)
        E = round(self.E_kPa / STRESS_UNIT_KPA, 6)
        return SensorConfig(resolution=(H, W), layers=layers, spacing=float(spacing), E=E, nu=min(self.nu, NU_SIM))

    def press_overrides(self, n_grid: int = 128, fill: float = DEFAULT_FILL) -> dict[str, float]:
        """``PressConfig`` fields that go with the pad: the hand speed for its nu, ``domain_size`` for meshes in mm."""
        return {
            "speed_fraction": round(speed_fraction_for(min(self.nu, NU_SIM)), 4),
            "domain_size": self.domain_mm(n_grid, fill),
        }


_GELSIGHT_E = "E not in the datasheet: ~0.1-0.25 MPa is what simulators and papers use for GelSight gels"

SENSOR_PRESETS: dict[str, SensorPreset] = {
    p.name: p
    for p in (
        SensorPreset(
            name="gelsight_mini",
            title="GelSight Mini",
            width_mm=18.6,
            height_mm=14.3,
            thickness_mm=4.25,
            E_kPa=150.0,
            nu=0.48,
            source="GelSight Mini datasheet (GelSight Inc., 2022): field of view 18.6 x 14.3 mm, gel 4.25 +- 0.2 mm. "
            + _GELSIGHT_E,
            approximate=("E_kPa", "nu"),
        ),
        SensorPreset(
            name="digit",
            title="DIGIT",
            width_mm=19.0,
            height_mm=16.0,
            thickness_mm=3.8,
            E_kPa=200.0,
            nu=0.48,
            source="Lambeta et al., DIGIT, IEEE RA-L 2020 (arXiv 2005.14679), Table I: 19 x 16 mm sensing field. "
            "Thickness: how far the gel stands out of the body in public CAD of the sensor (32.3 - 28.5 mm); "
            "E: typical soft silicone, not published",
            approximate=("thickness_mm", "E_kPa", "nu"),
            note="the DIGIT gel is slightly domed; the preset is flat",
        ),
        SensorPreset(
            name="gelsight_r15",
            title="GelSight R1.5",
            width_mm=28.1,
            height_mm=21.0,
            thickness_mm=4.0,
            E_kPa=150.0,
            nu=0.48,
            source="Area: the TacSL / Isaac Lab GelSight R1.5 render config (Akinola et al., TacSL, 2024): "
            "320 x 240 px at 0.0877 mm/px. Thickness: that of the GelSight Mini gel family, not published. "
            + _GELSIGHT_E,
            approximate=("thickness_mm", "E_kPa", "nu"),
        ),
        SensorPreset(
            name="tactip",
            title="TacTip",
            width_mm=40.0,
            height_mm=40.0,
            thickness_mm=13.3,
            E_kPa=100.0,
            nu=0.49,
            source="Ward-Cherrier et al., The TacTip Family, Soft Robotics 2018: 40 mm hemispherical tip, a "
            "moulded rubber skin filled with RTV27905 silicone gel. Thickness: the dome's mean depth "
            "(volume / footprint = 2R/3 with R = 20 mm); E: soft gel under a stiffer skin, an estimate",
            approximate=("thickness_mm", "E_kPa", "nu"),
            note="a gel-filled dome stood for by a flat 40 x 40 mm slab: contact images are a flat pad's",
        ),
    )
}


def _preset(name: str) -> SensorPreset:
    try:
        return SENSOR_PRESETS[name]
    except KeyError:
        raise ValueError(f"unknown sensor preset {name!r}; have {sorted(SENSOR_PRESETS)}") from None


def sensor_config(name: str, n_grid: int = 128, fill: float = DEFAULT_FILL, spacing: float = 0.5) -> SensorConfig:
    """:class:`SensorConfig` of preset ``name`` on an ``n_grid`` grid (see :meth:`SensorPreset.sensor_config`)."""
    return _preset(name).sensor_config(n_grid, fill=fill, spacing=spacing)


#: the fields of a preset's pad that its Hydra block ``configs/data/sensor/<name>.yaml`` reads with
#: ``${sensor_preset:<name>,<field>}`` (the rest of the block comes from ``configs/data/sensor/gel.yaml``)
PRESET_FIELDS = ("resolution", "layers", "E", "nu")


def preset_field(name: str, field: str, n_grid: int = 128) -> int | float | list[int]:
    """One field of preset ``name``'s pad at ``n_grid``, as a config holds it (``resolution`` a list [H, W]).

    The Hydra blocks of the sensor presets read their numbers here (the resolver ``sensor_preset`` that
    :mod:`tvrecon` registers), so the specs above are their one source.
    """
    if field not in PRESET_FIELDS:
        raise ValueError(f"sensor preset field must be one of {PRESET_FIELDS}, got {field!r}")
    value = getattr(sensor_config(name, int(n_grid)), field)
    return list(value) if isinstance(value, tuple) else value


def press_overrides(name: str, n_grid: int = 128, fill: float = DEFAULT_FILL) -> dict[str, float]:
    """``PressConfig`` fields of preset ``name`` (hand speed for its nu, ``domain_size`` for meshes in mm)."""
    return _preset(name).press_overrides(n_grid, fill=fill)


def pad_fits(sensor: SensorConfig, n_grid: int, gap: float = 1.0, max_depth: float = 4.0) -> bool:
    """Whether the pad and its travel fit the domain the way :mod:`tvrecon.sim.press.placement` lays them out.

    Laterally the collider box spans the pad's half extent + 3 cells each side of the domain centre; along the press
    axis the pad's thickness + gap + travel + 4 cells must stay under half the domain (``placement.pad_reach``).
    """
    hx, hy = sensor.half_extent
    lateral = max(hx, hy) + 3.0 < int(n_grid) / 2
    axial = sensor.thickness + float(gap) + float(max_depth) + 4.0 < int(n_grid) / 2
    return lateral and axial
