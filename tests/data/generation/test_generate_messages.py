"""A mistyped key in ``generate`` names the key and lists the real ones (before: Hydra suggested
``+train.num_sample=4``, and following that hint ended in a TypeError of the dataset)."""

from __future__ import annotations

import pytest

from tvrecon.data.generate import main
from tvrecon.data.presets import compose_preset
from tvrecon.utils.cli_errors import call_cli


def test_mistyped_key_lists_the_keys_of_its_parent(tmp_path, capsys) -> None:
    with pytest.raises(ValueError, match=r"unknown data key 'train.num_sample'.*'train' has .*'num_samples'"):
        compose_preset("tiny", ["train.num_sample=4"])
    prog = "python -m tvrecon.data.generate"
    assert call_cli(main, ["preset=tiny", "batch_sise=2", f"cache_dir={tmp_path}"], prog=prog) == 2
    lines = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(lines) == 1 and "unknown data key 'batch_sise'" in lines[0] and "'batch_size'" in lines[0]


def test_a_key_is_deleted_with_hydras_tilde() -> None:
    """``~key`` (Hydra's deletion) is an override, e.g. the paper preset's sweep order when its touches are the cone's;
    a lone ``~`` stays an error."""
    from tvrecon.data.generate import _parse

    opts, overrides = _parse(["preset=paper", "touch=cone", "~touch.order", "workers=1"])
    assert opts == {"preset": "paper", "workers": "1"} and overrides == ["touch=cone", "~touch.order"]
    with pytest.raises(ValueError, match="unexpected argument '~'"):
        _parse(["~"])
