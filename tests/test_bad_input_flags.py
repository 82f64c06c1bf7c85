"""Flags whose message misled: ``config show`` of the sections ``map --config`` takes, ``--config`` onto an
endless file, ``data fetch`` with an ftp mirror or a --dest that is a file. Each is one line naming the flag and
what it takes (exit 2), or the right answer."""

from __future__ import annotations

import pytest
from _cli import error_line
from _cli import run_cli_out as run_cli


@pytest.mark.parametrize("section, headers", [
    ("slam2d", ["map.slam2d"]), ("slam3d", ["map.slam3d"]), ("grids", ["map.grids"]),
    ("map", ["map.slam2d", "map.slam3d", "map.grids", "map.segmentation"]),
    ("map.segmentation", ["map.segmentation"]), ("slam", ["slam"]),
])
def test_config_show_shows_the_sections_map_config_takes(section, headers):
    """Before: ``config show slam2d`` (a section of ``map --config``) was 'no section', and ``map`` showed only
    map.grids."""
    code, out, _ = run_cli("config", "show", section)
    assert code == 0
    assert [line.split("]")[0][1:] for line in out.splitlines() if line.startswith("[")] == headers
    if section == "slam3d":
        assert "  dof: 6" in out.splitlines()


def test_config_show_lists_every_section_it_takes():
    """Before: the list omitted map and scenario, which it takes."""
    code, _, err = run_cli("config", "show", "nope")
    assert code == 2
    line = error_line(err)
    listed = line.split("the sections are ")[1]
    for name in ("slam", "map", "map.slam2d", "map.slam3d", "segmentation", "scenario", "scenario.robot"):
        assert name + "," in listed or name + " " in listed, line


@pytest.mark.parametrize("command", ["segment", "map"])
def test_config_onto_an_endless_file_is_bounded(tmp_path, command):
    """Before: ``--config /dev/zero`` read until MemoryError."""
    import numpy as np
    from PIL import Image

    Image.fromarray(np.full((20, 20), 254, np.uint8)).save(tmp_path / "m.png")
    code, _, err = run_cli(command, tmp_path / "m.png", "--out", tmp_path / "o", "--config", "/dev/zero")
    assert code == 2
    assert error_line(err).startswith("/dev/zero: more than 16777216 bytes; expected a configuration file")


def test_an_ftp_mirror_is_refused_at_once(tmp_path, monkeypatch):
    """Before: ftp:// passed the check, then the download failed with requests' InvalidSchema."""
    monkeypatch.delenv("HSMAP_DATA_MIRROR", raising=False)
    code, _, err = run_cli("data", "fetch", "octomap", "--mirror", "ftp://example.org/d", "--dest", tmp_path / "d")
    assert code == 2
    assert error_line(err) == "mirror must be an http:// or https:// URL, got 'ftp://example.org/d'"
    assert not (tmp_path / "d").exists()


def test_a_dest_that_is_a_file_is_named(tmp_path):
    """Before: '[Errno 17] File exists'."""
    f = tmp_path / "file"
    f.write_text("x")
    code, _, err = run_cli("data", "fetch", "octomap", "--dest", f)
    assert code == 2
    assert error_line(err) == f"--dest {f}: exists and is not a folder"
