"""``eval.py cls_fuse=[...]``: test a trained classifier together with others, answers combined (beyond the paper).

The classifier of ``ckpt_path`` / ``run_dir`` (the primary) keeps its run's data, evaluation and Table 2 protocol; the
classifiers named by ``cls_fuse`` (run folders or checkpoint files) are rebuilt from their own runs and asked on the
same batches, and :class:`~tvrecon.models.components.late_fusion.LateFusionClassifier` combines the class
probabilities. Nothing is trained. The members must have been trained on the primary's data: the same library, split
protocol, touches and images; only what adds inputs (``patches``), acts in training only (``rotate_pose``) or sets the
loader differs, and the image size where the member does not read the images.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import hydra
from omegaconf import DictConfig, OmegaConf, open_dict
from torch import nn

from tvrecon.models.components.late_fusion import LateFusionClassifier
from tvrecon.models.heading_ensemble import check_headings
from tvrecon.report.table_format import PRETTY_NAMES
from tvrecon.utils.checkpoint import load_run

__all__ = ["TrainedClassifier", "data_mismatch", "fuse_data_config", "fuse_into", "load_trained_classifier"]

log = logging.getLogger(__name__)

#: data keys a member may set differently from the primary: inputs added, training-only augmentation, the loader
FREE_DATA_KEYS = frozenset({"patches", "rotate_pose", "batch_size", "num_workers", "pin_memory"})
#: data keys that only shape the tactile images (free for a member that does not read them)
IMAGE_DATA_KEYS = frozenset({"tactile_size", "device_tactile_size"})


@dataclass(frozen=True)
class TrainedClassifier:
    """A trained classifier rebuilt from its run.

    Attributes:
        ckpt: the checkpoint its weights came from.
        run_cfg: its run's ``.hydra/config.yaml``.
        net: the network (eval mode).
        touches: the touch counts it can answer: its N (``touch_sampling: fixed``, the paper's one model per N) or
            1..N (``random``).
        name: its experiment name.
    """

    ckpt: Path
    run_cfg: DictConfig
    net: nn.Module
    touches: frozenset[int]
    name: str


def load_trained_classifier(ckpt: Path) -> TrainedClassifier:
    """Rebuild the classifier of ``ckpt`` from its run's config (``<run>/.hydra/config.yaml``) and load its weights.

    Raises:
        FileNotFoundError: the run's config does not exist.
        CorruptCheckpointError: the checkpoint cannot be read (names the file).
        ValueError: the run is not a classifier.
    """
    state, run_cfg = load_run(ckpt, "cls_fuse", "name a checkpoint inside its train.py run folder")
    target = str(run_cfg.model.get("_target_", ""))
    if not target.endswith("ClassificationModule"):
        raise ValueError(f"cls_fuse: {ckpt} holds {target or 'no model'}, not a classifier: only classifiers fuse")
    module = hydra.utils.instantiate(run_cfg.model)
    module.load_state_dict(state["state_dict"])
    module.eval()
    n = int(module.num_touches)
    touches = frozenset({n} if module.touch_sampling == "fixed" else range(1, n + 1))
    name = str(run_cfg.get("experiment_name") or module.hparams.get("name", "classify"))
    return TrainedClassifier(ckpt=ckpt, run_cfg=run_cfg, net=module.net, touches=touches, name=name)


def _flat(cfg: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """``{"a.b": leaf}`` of a nested mapping (lists as leaves)."""
    out: dict[str, Any] = {}
    for key, value in cfg.items():
        path = f"{prefix}{key}"
        if isinstance(value, Mapping):
            out.update(_flat(value, path + "."))
        else:
            out[path] = value
    return out


def data_mismatch(primary: DictConfig, member: DictConfig, reads_images: bool) -> list[str]:
    """The data keys (dotted) where ``member``'s run data differs from ``primary``'s in a way that matters.

    Args:
        primary, member: the two runs' ``data`` configs (unresolved).
        reads_images: the member reads the tactile images (then their size must match too).
    """
    free = FREE_DATA_KEYS | (frozenset() if reads_images else IMAGE_DATA_KEYS)
    a = _flat(OmegaConf.to_container(primary, resolve=False))  # type: ignore[arg-type]
    b = _flat(OmegaConf.to_container(member, resolve=False))  # type: ignore[arg-type]
    return sorted(k for k in a.keys() | b.keys() if a.get(k) != b.get(k) and k.split(".")[0] not in free)


def fuse_data_config(primary: DictConfig, data: DictConfig, members: Sequence[TrainedClassifier]) -> None:
    """Check every member was trained on the primary's data, and let ``data`` (what is tested) serve their inputs.

    Args:
        primary: the primary run's own ``data`` config (what it was trained on).
        data: the data config the evaluation will use (the primary's, or eval.py's ``data=``); edited in place.
        members: the other classifiers.

    Raises:
        ValueError: a member trained on other data (names the keys and both values).
    """
    for member in members:
        reads = tuple(getattr(member.net, "touch_inputs", ("tactile",)))
        images = bool(getattr(member.net, "reads_images", "tactile" in reads))
        diff = data_mismatch(primary, member.run_cfg.data, images)
        if diff:
            a = _flat(OmegaConf.to_container(primary, resolve=False))  # type: ignore[arg-type]
            b = _flat(OmegaConf.to_container(member.run_cfg.data, resolve=False))  # type: ignore[arg-type]
            shown = ", ".join(f"{k}: {a.get(k)!r} vs {b.get(k)!r}" for k in diff[:6])
            raise ValueError(
                f"cls_fuse: {member.ckpt} was trained on other data than the evaluated classifier ({shown}"
                f"{', ...' if len(diff) > 6 else ''}): fuse classifiers trained on the same data"
            )
        if any(k.startswith("patch_") for k in reads) and not data.get("patches"):
            with open_dict(data):
                data.patches = True  # the member reads the contact patches: serve them (adds inputs only)


def fuse_into(module: nn.Module, members: Sequence[TrainedClassifier], rule: str) -> str:
    """Replace a trained classification module's network by the late fusion of it and ``members``, in place.

    The module keeps its evaluation protocol: the touch counts it tests become those every member can answer, the
    test also scores another object's touches (the ``"other"`` control), and its results are named after all members.

    Args:
        module: a :class:`~tvrecon.models.lit_cls.ClassificationModule` with its weights loaded.
        members: the other classifiers (:func:`load_trained_classifier`).
        rule: one of :data:`~tvrecon.models.components.late_fusion.FUSION_RULES`.

    Returns:
        The fused result's name (its Table 2 row), e.g. ``"Late fusion (mean_log_prob, beyond the paper): Tactile
        classifier + Contact-cloud classifier"``.

    Raises:
        ValueError: no touch count the module tests is one every member can answer.
    """
    fused = LateFusionClassifier([module.net, *[m.net for m in members]], rule)
    touches = set(module.eval_touches)
    for member in members:
        touches &= member.touches
    if not touches:
        can = "; ".join(f"{m.ckpt}: {sorted(m.touches)}" for m in members)
        raise ValueError(
            f"cls_fuse: no touch count is both tested by the evaluated classifier ({module.eval_touches}) and answered "
            f"by every fused classifier ({can}): a paper classifier answers only its own N, so fuse the N=k model "
            f"with the others"
        )
    module.net = fused.eval()
    module.touch_inputs = fused.touch_inputs
    module.headings = check_headings(module.headings, module.touch_inputs)
    module.eval_touches = sorted(touches)
    if "other" not in module.controls:
        module.controls = [*module.controls, "other"]
    names = [str(module.hparams.get("name", "classify")), *[m.name for m in members]]
    labels = [PRETTY_NAMES.get(n, n).replace(" (beyond the paper)", "") for n in names]
    name = f"Late fusion ({rule}, beyond the paper): " + " + ".join(labels)
    module.hparams.name = name
    log.info("fused %d classifiers (%s), tested at %s touches", len(members) + 1, rule, module.eval_touches)
    return name
