from dataclasses import dataclass, field

import pytest

from tvrecon.utils.config_utils import check_known_keys, coerce_config, field_names


@dataclass
class _Inner:
    size: tuple[int, int] = (4, 4)
    scale: float = 1.0


@dataclass
class _Outer:
    name: str = "a"
    inner: _Inner = field(default_factory=_Inner)


def test_coerce_config_builds_nested_and_normalizes_values() -> None:
    assert coerce_config(_Outer, None) == _Outer()
    cfg = _Outer(name="b")
    assert coerce_config(_Outer, cfg) is cfg
    out = coerce_config(_Outer, {"name": "c", "inner": {"size": [2, 3], "scale": 2}})
    assert out.inner == _Inner(size=(2, 3), scale=2.0) and isinstance(out.inner.scale, float)
    assert field_names(_Outer) == ("name", "inner")


def test_unknown_keys_name_the_config_and_list_the_valid_ones() -> None:
    with pytest.raises(ValueError, match=r"unknown demo option\(s\) \['nmae'\]; valid: \['inner', 'name'\]"):
        coerce_config(_Outer, {"nmae": "x"}, "demo")
    with pytest.raises(ValueError, match=r"unknown inner option\(s\) \['sise'\]"):
        coerce_config(_Outer, {"inner": {"sise": 3}})
    with pytest.raises(ValueError, match="_Outer config must be a _Outer or a mapping"):
        coerce_config(_Outer, 3)  # type: ignore[arg-type]
    check_known_keys(["a"], ["a", "b"], "x")
    with pytest.raises(ValueError, match=r"unknown x option\(s\) \['c'\]"):
        check_known_keys(["c"], ["a", "b"], "x")
