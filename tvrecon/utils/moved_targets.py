"""Module paths of earlier releases, so a run folder written before the package layout changed still evaluates.

``eval.py`` rebuilds every checkpoint's model and data from its run's ``.hydra/config.yaml``, whose ``_target_``
strings name the modules of the release that trained it. :func:`upgrade_targets` rewrites the ones whose module has
moved since (``tvrecon.models.fusion.TactileVisualFusion`` -> ``tvrecon.models.components.fusion...``) and leaves
everything else alone. The module depends on no other part of ``tvrecon``.
"""

from __future__ import annotations

from typing import Any

from omegaconf import DictConfig, ListConfig, OmegaConf

__all__ = ["MOVED_MODULES", "upgrade_target", "upgrade_targets"]

# old module -> the module that holds its names now (the layout of tvrecon/sim, utils/, report/, models/components/)
MOVED_MODULES: dict[str, str] = {
    "tvrecon.data.generated": "tvrecon.data.generated_dataset",
    "tvrecon.data.shapes.contact": "tvrecon.data.shapes.sheet",
    "tvrecon.data.render": "tvrecon.data.views",
    "tvrecon.models.backbone": "tvrecon.models.components.backbone",
    "tvrecon.models.classifier": "tvrecon.models.components.classifier",
    "tvrecon.models.contact_cloud": "tvrecon.models.components.contact_cloud",
    "tvrecon.models.ellipsoid": "tvrecon.models.components.ellipsoid",
    "tvrecon.models.fusion": "tvrecon.models.components.fusion",
    "tvrecon.models.gcn": "tvrecon.models.components.gcn",
    "tvrecon.models.projection": "tvrecon.models.components.projection",
    "tvrecon.models.reconstructor": "tvrecon.models.components.reconstructor",
    "tvrecon.models.set_pool": "tvrecon.models.components.set_pool",
    "tvrecon.models.touch_geometry": "tvrecon.models.components.touch_geometry",
    "tvrecon.models.touch_set": "tvrecon.models.components.touch_set",
    "tvrecon.cls_report": "tvrecon.report.cls_report",
    "tvrecon.run": "tvrecon.report.run",
    "tvrecon.seed_summary": "tvrecon.report.seed_summary",
    "tvrecon.table_format": "tvrecon.report.table_format",
    "tvrecon.tables": "tvrecon.report.tables",
    "tvrecon.viz": "tvrecon.report.viz",
    "tvrecon.sim.colliders": "tvrecon.sim.bodies.colliders",
    "tvrecon.sim.mesh_distance": "tvrecon.sim.bodies.mesh_distance",
    "tvrecon.sim.mesh_region": "tvrecon.sim.bodies.mesh_region",
    "tvrecon.sim.mesh_sign": "tvrecon.sim.bodies.mesh_sign",
    "tvrecon.sim.voxelize": "tvrecon.sim.bodies.voxelize",
    "tvrecon.sim.mpm_compiled_grid": "tvrecon.sim.mpm.compiled.grid",
    "tvrecon.sim.mpm_compiled": "tvrecon.sim.mpm.compiled.kernels",
    "tvrecon.sim.mpm_scatter": "tvrecon.sim.mpm.compiled.scatter",
    "tvrecon.sim.mpm_fused": "tvrecon.sim.mpm.compiled.step",
    "tvrecon.sim.mpm_grid": "tvrecon.sim.mpm.grid",
    "tvrecon.sim.materials": "tvrecon.sim.mpm.materials",
    "tvrecon.sim.particle_contact": "tvrecon.sim.mpm.particle_contact",
    "tvrecon.sim.reference": "tvrecon.sim.mpm.reference",
    "tvrecon.sim.render": "tvrecon.sim.plots",
    "tvrecon.sim.press_run": "tvrecon.sim.press.loop",
    "tvrecon.sim.placement": "tvrecon.sim.press.placement",
    "tvrecon.sim.stop_rules": "tvrecon.sim.press.stop_rules",
    "tvrecon.sim.forces": "tvrecon.sim.sensor.forces",
    "tvrecon.sim.markers": "tvrecon.sim.sensor.markers",
    "tvrecon.sim.contact": "tvrecon.sim.sensor.patch",
    "tvrecon.sim.photometric": "tvrecon.sim.sensor.photometric",
    "tvrecon.sim.sensor_presets": "tvrecon.sim.sensor.presets",
    "tvrecon.sim.reconstruct": "tvrecon.sim.sensor.surface",
    "tvrecon.atomic": "tvrecon.utils.atomic",
    "tvrecon.checkpoint": "tvrecon.utils.checkpoint",
    "tvrecon.cli_errors": "tvrecon.utils.cli_errors",
    "tvrecon.config_utils": "tvrecon.utils.config_utils",
    "tvrecon.geometry": "tvrecon.utils.geometry",
}


def upgrade_target(target: str) -> str:
    """``target`` (``"pkg.module.Name"``) with a moved module replaced by its new path; others unchanged."""
    module, _, name = target.rpartition(".")
    new = MOVED_MODULES.get(module)
    return f"{new}.{name}" if new is not None else target


def upgrade_targets(cfg: DictConfig | ListConfig | dict | list) -> list[tuple[str, str]]:
    """Rewrite, in place, every ``_target_`` of a nested config that names a moved module.

    Interpolations (``${hydra:...}``, ``${paths...}``) are skipped, not resolved.

    Returns:
        The ``(old, new)`` pairs rewritten, in the order met (empty for a config of this release).
    """
    changed: list[tuple[str, str]] = []

    def walk(node: Any) -> None:
        if isinstance(node, (DictConfig, dict)):
            for key in list(node.keys()):
                if isinstance(node, DictConfig) and OmegaConf.is_interpolation(node, key):
                    continue
                value = node[key]
                if key == "_target_" and isinstance(value, str):
                    new = upgrade_target(value)
                    if new != value:
                        node[key] = new
                        changed.append((value, new))
                else:
                    walk(value)
        elif isinstance(node, (ListConfig, list)):
            for i in range(len(node)):
                if not (isinstance(node, ListConfig) and OmegaConf.is_interpolation(node, i)):
                    walk(node[i])

    walk(cfg)
    return changed
