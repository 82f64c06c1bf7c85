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


def test_every_setting_has_a_default_and_a_meaning():
    from hsmap.commands.config import reference

    rows = [row for section in reference().values() for row in section]
    assert len(rows) > 150
    assert [k for k, _, m in rows if not m] == []
    slam = dict((k, (d, m)) for k, d, m in reference("slam")["slam"])
    assert slam["graph.pair_edges"][0] == "4" and "pair" in slam["graph.pair_edges"][1]
    assert slam["loop_closure.far_corroborate_within"][0] == "20"
    assert set(reference("scenario")) == {"scenario.robot", "scenario.odometry", "scenario.sensors.lidar2d",
                                          "scenario.sensors.lidar3d"}


def test_field_docs_reads_grouped_entries():
    from dataclasses import dataclass

    from hsmap.config import config_reference, field_docs

    @dataclass
    class C:
        """Settings.

        Attributes
        ----------
        a, b : float
            Two lengths,
            in metres.
        c : bool
            A switch.

        Notes
        -----
        c : not a field
        """

        a: float = 1.0
        b: float = 0.5
        c: bool = True

    assert field_docs(C) == {"a": "Two lengths, in metres.", "b": "Two lengths, in metres.", "c": "A switch."}
    assert config_reference(C()) == [("a", "1", "Two lengths, in metres."), ("b", "0.5", "Two lengths, in metres."),
                                     ("c", "true", "A switch.")]


def test_docs_config_md_is_the_generated_reference():
    from pathlib import Path

    from hsmap.commands.config import markdown

    doc = Path(__file__).resolve().parents[1] / "docs" / "CONFIG.md"
    assert doc.read_text(encoding="utf-8") == markdown() + "\n", "regenerate: hsmap config show --markdown > docs/CONFIG.md"


def test_config_show_prints_a_section_and_refuses_an_unknown_one(capsys):
    from hsmap.cli import main

    assert main(["config", "show", "map.grids"]) == 0
    out = capsys.readouterr().out
    assert "  slice: [1.7, 1.8]\n" in out and "  resolution: 0.05\n" in out
    assert main(["config", "show", "slams"]) == 2
    assert "no section 'slams'" in capsys.readouterr().err


def test_the_loop_search_settings_are_read_from_their_earlier_place_with_a_warning(tmp_path):
    from hsmap.errors import HsmapWarning
    from hsmap.slam.config import SlamConfig

    data = {"graph": {"search_every": 3, "far_every": 7, "pair_edges": 2}}
    with pytest.warns(HsmapWarning, match=r"slam\.graph\.(search|far)_every is read as slam\.loop_closure\.\1_every"):
        cfg = from_dict(SlamConfig, data, "slam")
    assert (cfg.loop_closure.search_every, cfg.loop_closure.far_every, cfg.graph.pair_edges) == (3, 7, 2)
    assert data == {"graph": {"search_every": 3, "far_every": 7, "pair_edges": 2}}  # the caller's mapping unchanged
    with pytest.raises(ConfigError, match=r"slam\.loop_closure\.far_every is given twice"):
        from_dict(SlamConfig, {"graph": {"far_every": 3}, "loop_closure": {"far_every": 2}}, "slam")
    dump_config(cfg, tmp_path / "slam.yaml")
    assert load_config(SlamConfig, tmp_path / "slam.yaml") == cfg
