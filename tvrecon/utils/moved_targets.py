"""Module paths of earlier releases, so a run folder written before the package layout changed still evaluates.

``eval.py`` rebuilds every checkpoint's model and data from its run's ``.hydra/config.yaml``, whose ``_target_``
strings name the modules of the release that trained it. :func:`upgrade_targets` rewrites the ones whose module has
moved since (``tvrecon.models.fusion.TactileVisualFusion`` -> ``tvrecon.models.components.fusion...``) and leaves
everything else alone. The module depends on no other part of ``tvrecon``.

Only modules that a run config can name are listed: those that held a ``_target_`` of ``configs/`` (models, callbacks,
touch policies) when they moved. A module that never held one (the simulator's, the reports', the helpers') is not
named by any run folder, so its old path is not kept here. Each entry is kept until 2027-06-30 (every run folder of the
layout it upgrades is then at least six months old; its config can still be edited by hand) and dropped after it.
"""

from __future__ import annotations

from typing import Any

from omegaconf import DictConfig, ListConfig, OmegaConf

__all__ = ["MOVED_MODULES", "upgrade_target", "upgrade_targets"]

# old module -> the module that holds its names now; each kept until 2027-06-30
MOVED_MODULES: dict[str, str] = {
    # models/components/ (the networks apart from the LightningModules)
    "tvrecon.models.backbone": "tvrecon.models.components.backbone",
    "tvrecon.models.classifier": "tvrecon.models.components.classifier",
    "tvrecon.models.contact_cloud": "tvrecon.models.components.contact_cloud",
    "tvrecon.models.fusion": "tvrecon.models.components.fusion",
    "tvrecon.models.gcn": "tvrecon.models.components.gcn",
    "tvrecon.models.reconstructor": "tvrecon.models.components.reconstructor",
    "tvrecon.models.touch_geometry": "tvrecon.models.components.touch_geometry",
    "tvrecon.models.touch_set": "tvrecon.models.components.touch_set",
    # train/ (the callbacks beside the run plumbing) and data/touches/ (the touch policies)
    "tvrecon.models.bn_recalibrate": "tvrecon.train.bn_recalibrate",
    "tvrecon.models.grad_norm": "tvrecon.train.grad_norm",
    "tvrecon.data.touches": "tvrecon.data.touches.policies",
    "tvrecon.data.touch_sweep": "tvrecon.data.touches.sweep",
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
