"""The documentation site builds with ``mkdocs build --strict``: a broken link, a page missing from the nav or an API
name mkdocstrings cannot resolve fails the build (``make docs`` runs the same build into ``site/``)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

pytest.importorskip("mkdocs", reason="the docs extra (pip install -e '.[docs]'; make test installs it)")
pytest.importorskip("mkdocstrings_handlers.python", reason="the docs extra (mkdocstrings[python])")
pytest.importorskip("material", reason="the docs extra (mkdocs-material)")


def test_site_builds_strict(tmp_path: Path) -> None:
    env = {**os.environ, "PYTHONPATH": str(ROOT), "NO_MKDOCS_2_WARNING": "1"}
    cmd = [sys.executable, "-m", "mkdocs", "build", "--strict", "--config-file", str(ROOT / "mkdocs.yml")]
    done = subprocess.run([*cmd, "--site-dir", str(tmp_path / "site")], cwd=ROOT, env=env, capture_output=True,
                          text=True, timeout=600)
    warnings = [line for line in done.stderr.splitlines() if "WARNING" in line or "ERROR" in line]
    shown = warnings or done.stderr.splitlines()[-20:]
    assert done.returncode == 0, "mkdocs build --strict failed:\n" + "\n".join(shown)
    for page in ("index.html", "guides/simulator/index.html", "api/sim/index.html"):
        assert (tmp_path / "site" / page).is_file(), page
    api = (tmp_path / "site" / "api" / "sim" / "index.html").read_text()
    assert 'id="tvrecon.sim.EIPSimulator"' in api  # the API pages hold the docstrings, not just a heading
