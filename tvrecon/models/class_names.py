"""Class names for the test reports: from the module's config, else from the datamodule's object library."""

from __future__ import annotations

from typing import Any


def datamodule_class_names(trainer: Any) -> list[str]:
    """``trainer.datamodule.library.classes`` as strings; [] when the trainer, datamodule or library has none.

    Args:
        trainer: a Lightning trainer (or None, e.g. a module used outside ``Trainer.test``).
    Returns:
        the class names in label order (label i is ``names[i]``), or [].
    """
    library = getattr(getattr(trainer, "datamodule", None), "library", None)
    classes = getattr(library, "classes", None)
    return [str(c) for c in classes] if classes is not None else []
