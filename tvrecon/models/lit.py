"""LightningModules of the project (the layout name of DESIGN.md); the code lives in one file per task.

- :class:`~tvrecon.models.lit_recon.ReconstructionModule`: tactile-visual mesh reconstruction (Tables 3, 4).
- :class:`~tvrecon.models.lit_cls.ClassificationModule`: N-touch tactile classification (Table 2).
"""

from tvrecon.models.lit_cls import ClassificationModule
from tvrecon.models.lit_recon import ReconstructionModule

__all__ = ["ClassificationModule", "ReconstructionModule"]
