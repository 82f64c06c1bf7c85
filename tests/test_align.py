"""hsmap align and hsmap.maps.fusion.global_align: two maps of one building registered with no initial guess."""

from __future__ import annotations

import json

import numpy as np
import pytest

from hsmap.cli import main
from hsmap.geometry import pose_to_matrix
from hsmap.maps.fusion import GlobalSearch, global_align
from hsmap.maps.grid import OCCUPIED, UNKNOWN, GridGeometry, OccupancyGrid, write_map
from hsmap.testing import office_segments

RES = 0.05
TRUE = np.array([12.3, -4.1, np.deg2rad(117.0)])  # map A's frame -> map B's frame


def _points(segments: np.ndarray, step: float = 0.02) -> np.ndarray:
    out = []
    for a, b in segments:
        n = max(int(np.ceil(np.linalg.norm(b - a) / step)), 1)
        t = np.linspace(0.0, 1.0, n + 1)[:, None]
        out.append(a + t * (b - a))
    return np.vstack(out)


def _grid(points: np.ndarray) -> OccupancyGrid:
    geo = GridGeometry.covering(points.min(0), points.max(0), RES, margin=1.0)
    data = np.full(geo.shape, UNKNOWN, dtype=np.int8)
    rc = geo.world_to_index(points)
    data[rc[:, 0], rc[:, 1]] = OCCUPIED
    return OccupancyGrid(data, geo)


@pytest.fixture(scope="module")
def pair() -> tuple[OccupancyGrid, OccupancyGrid]:
    """Map A: the furnished two-room office, whole. Map B: its walls only (no furniture), east of x = 6 m (the
    corridor's end and room B), in a frame turned by 117 deg and moved by (12.3, -4.1)."""
    segs = office_segments()
    a = _points(segs)
    walls = _points(segs[:12])
    walls = walls[walls[:, 0] > 6.0]
    T = pose_to_matrix(TRUE)
    b = walls @ T[:2, :2].T + T[:2, 2]
    rng = np.random.default_rng(7)
    return _grid(a + rng.normal(0, 0.01, a.shape)), _grid(b + rng.normal(0, 0.01, b.shape))


def _angle_deg(a: float, b: float) -> float:
    return float(np.rad2deg(abs((a - b + np.pi) % (2 * np.pi) - np.pi)))


@pytest.mark.parametrize("seed", [1, 2])
def test_global_align_finds_a_partial_map_in_any_pose(pair, seed):
    a, b = pair
    al, candidates = global_align(a, b, rng=seed)
    assert np.linalg.norm(al.pose[:2] - TRUE[:2]) < 0.05
    assert _angle_deg(al.pose[2], TRUE[2]) < 0.5
    assert len(candidates) == 2 and {c["direction"] for c in candidates} == {"floor onto slice",
                                                                             "slice onto floor"}
    # map B is all walls of map A: it is matched almost entirely, map A (furniture, room A) only in part
    assert al.slice_matched > 0.9
    assert al.floor_matched < 0.8
    assert al.registration.rmse < 0.05


def test_global_search_settings_are_checked():
    from hsmap.errors import ConfigError

    with pytest.raises(ConfigError, match="angle_step_deg"):
        GlobalSearch(angle_step_deg=0.0)


def test_align_command_writes_the_transform_and_overlay(pair, tmp_path, capsys):
    from PIL import Image

    a, b = pair
    write_map(tmp_path / "a.yaml", a)
    write_map(tmp_path / "b.yaml", b)
    out = tmp_path / "out"
    assert main(["align", str(tmp_path / "a.yaml"), str(tmp_path / "b.yaml"), "--out", str(out), "--seed", "3"]) == 0
    assert "MAP2D -> MAP3D" in capsys.readouterr().out
    res = json.loads((out / "alignment.json").read_text())
    t = res["transform"]
    assert np.hypot(t["x"] - TRUE[0], t["y"] - TRUE[1]) < 0.05
    assert _angle_deg(np.deg2rad(t["yaw_deg"]), TRUE[2]) < 0.5
    assert 0 < res["overlap"]["overlap"] <= 1 and res["residual"]["rmse"] < 0.05
    # map B lies wholly inside map A's box; A reaches beyond B's (room A and the corridor's west part)
    assert res["coverage"]["map3d_in_map2d"]["inside_other_box"] > 0.99
    assert res["coverage"]["map2d_in_map3d"]["inside_other_box"] < 0.8
    img = np.asarray(Image.open(out / "overlay.png"))
    assert img.ndim == 3 and img.shape[2] == 3
    # dark (seen by both), red (map A only) and blue (map B only) structure all appear
    dark = (img.max(axis=2) < 60).sum()
    red = ((img[..., 0] > 180) & (img[..., 1] < 80)).sum()
    assert dark > 0 and red > 0
    for name in ("map2d_aligned.yaml", "map2d_aligned.pgm", "map3d_band.yaml", "map3d_band.pgm"):
        assert (out / name).is_file()


@pytest.mark.parametrize("args, words", [
    (["--band", "1.8,1.7"], "--band must be LO,HI with LO < HI"),
    (["--band", "x"], "--band must be 2"),
    (["--resolution", "-1"], "--resolution"),
])
def test_align_bad_flags_are_one_line_errors(pair, tmp_path, capsys, args, words):
    a, b = pair
    write_map(tmp_path / "a.yaml", a)
    write_map(tmp_path / "b.yaml", b)
    assert main(["align", str(tmp_path / "a.yaml"), str(tmp_path / "b.yaml"), "--out", str(tmp_path / "o"),
                 *args]) == 2
    err = capsys.readouterr().err
    assert words in err and err.count("\n") == 1


def test_align_missing_or_damaged_maps(tmp_path, capsys):
    (tmp_path / "bad.bt").write_bytes(b"# Octomap OcTree binary file\nid OcTree\nsize 9\nres 0.1\ndata\n\x03")
    (tmp_path / "a.png").write_bytes(b"not a png")
    assert main(["align", str(tmp_path / "none.yaml"), str(tmp_path / "bad.bt"), "--out", str(tmp_path / "o")]) == 2
    assert "none.yaml" in capsys.readouterr().err
    from PIL import Image

    Image.fromarray(np.full((40, 40), 254, np.uint8)).save(tmp_path / "ok.png")
    assert main(["align", str(tmp_path / "ok.png"), str(tmp_path / "bad.bt"), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "bad.bt" in err and "truncated" in err and err.count("\n") == 1
