"""``benchmarks`` is a package at the repository root, imported by module path like the scripts' own ``python -m
benchmarks...``. ``python -m pytest`` (what ``make test`` runs) has the root on ``sys.path`` already; a bare ``pytest``
gets it here."""

import sys
from pathlib import Path

ROOT = str(Path(__file__).resolve().parents[2])
if ROOT not in sys.path:
    sys.path.insert(0, ROOT)
