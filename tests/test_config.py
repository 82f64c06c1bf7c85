from dataclasses import dataclass, field

import pytest

from hsmap.config import dump_config, from_dict, load_config
from hsmap.errors import ConfigError


@dataclass
class Inner:
    a: int = 1


@dataclass
class Outer:
    x: float = 0.5
    inner: Inner = field(default_factory=Inner)


def test_roundtrip(tmp_path):
    cfg = Outer(x=2.0, inner=Inner(a=7))
    dump_config(cfg, tmp_path / "c.yaml")
    assert load_config(Outer, tmp_path / "c.yaml") == cfg


def test_unknown_key_is_named():
    with pytest.raises(ConfigError, match=r"cfg.inner: unknown key\(s\) \['b'\]"):
        from_dict(Outer, {"inner": {"b": 1}}, "cfg")
