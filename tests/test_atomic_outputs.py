"""A failed, refused or interrupted command leaves what was there as it was, and nothing of its own: a dataset
folder a new simulation was to replace, an input of ``hsmap align`` inside its output folder, a download's
destination, the default output folder under ``data/generated/``.

The output faults of the other commands (full disk, signals, a damaged cache) are in ``test_faults.py``."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from hsmap.cli import main
from hsmap.errors import HsmapError
from hsmap.sim import voxelrun
from hsmap.sim.sensors import Lidar2DConfig, Lidar3DConfig
from hsmap.sim.voxelrun import WorldRunConfig, simulate_world
from hsmap.sim.voxelworld import FREE, OCCUPIED, UNKNOWN, VoxelWorld

RES = 0.1


def _office() -> VoxelWorld:
    """A corridor (x 0-8 m, y 0-2) with a room (x 3-7, y 2-6) through a 1.2 m door, walls, floor and ceiling."""
    nx, ny, nz = 84, 64, 28
    st = np.full((nx, ny, nz), UNKNOWN, np.uint8)
    ix = lambda x: int(round(x / RES)) + 2  # noqa: E731
    st[ix(0):ix(8), ix(0):ix(2), 1:27] = FREE
    st[ix(3):ix(7), ix(2):ix(6), 1:27] = FREE
    st[:, :, 0] = st[:, :, 27] = OCCUPIED
    wall = np.zeros((nx, ny), bool)
    wall[ix(0) - 1:ix(8) + 1, ix(0) - 1] = wall[ix(0) - 1:ix(3) + 1, ix(2)] = True
    wall[ix(7) - 1:ix(8) + 1, ix(2)] = wall[ix(3):ix(4.4), ix(2)] = wall[ix(5.6):ix(7), ix(2)] = True
    wall[ix(3) - 1, ix(2):ix(6) + 1] = wall[ix(7), ix(2):ix(6) + 1] = wall[ix(3) - 1:ix(7) + 1, ix(6)] = True
    wall[ix(0) - 1, :ix(2)] = wall[ix(8), :ix(2) + 1] = True
    st[wall, 1:27] = OCCUPIED
    return VoxelWorld(st, (-0.2, -0.2, -0.1), RES, floor=0.0, source="office")


CFG = WorldRunConfig(lidar3d=Lidar3DConfig(channels=8, columns=128), lidar2d=Lidar2DConfig())


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def world_dataset(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("world") / "dataset"
    simulate_world(_office(), out, seed=1, config=CFG, max_frames=3)
    return out


@pytest.mark.parametrize("fault", [KeyboardInterrupt, OSError])
def test_an_interrupted_world_run_leaves_the_previous_dataset_whole(world_dataset, tmp_path, monkeypatch, fault):
    """Before: the folder's dataset.yaml was deleted before the new run started; an interrupt, a full disk or a
    failure while writing left the old dataset unreadable."""
    import shutil

    folder = tmp_path / "dataset"
    shutil.copytree(world_dataset, folder)
    before = _snapshot(folder)

    def broken(*a, **k):
        raise fault("stopped while writing")

    monkeypatch.setattr(voxelrun, "write_route_files", broken)
    with pytest.raises(fault):
        simulate_world(_office(), folder, seed=2, config=CFG, max_frames=2)
    assert _snapshot(folder) == before
    assert sorted(p.name for p in folder.iterdir()) == sorted(p.name for p in world_dataset.iterdir())


def test_a_world_run_refused_before_writing_leaves_the_previous_dataset_whole(world_dataset, tmp_path):
    import shutil

    folder = tmp_path / "dataset"
    shutil.copytree(world_dataset, folder)
    before = _snapshot(folder)
    walled = _office()
    walled.state[:, :, 1:27][walled.state[:, :, 1:27] == FREE] = OCCUPIED  # no free space left
    with pytest.raises(HsmapError):
        simulate_world(walled, folder, seed=2, config=CFG, max_frames=2)
    assert _snapshot(folder) == before


def test_a_world_run_replaces_a_previous_dataset_whole(world_dataset, tmp_path):
    folder = tmp_path / "dataset"
    simulate_world(_office(), folder, seed=1, config=CFG, max_frames=3)
    (folder / "clouds3d" / "000099.npz").write_bytes(b"stale")
    run = simulate_world(_office(), folder, seed=1, config=CFG, max_frames=2)
    assert run.path == folder and (folder / "dataset.yaml").is_file()
    assert sorted(p.name for p in (folder / "clouds3d").iterdir()) == ["000000.npz", "000001.npz"]
    assert not [p for p in folder.iterdir() if p.name.startswith(".")]


def test_a_failed_world_run_leaves_no_folder_it_created(tmp_path):
    """Before: a run that failed after the folder was made left it empty (under data/generated/ without --out)."""
    walled = _office()
    walled.state[:, :, 1:27][walled.state[:, :, 1:27] == FREE] = OCCUPIED
    with pytest.raises(HsmapError):
        simulate_world(walled, tmp_path / "new" / "dataset", seed=2, config=CFG, max_frames=2)
    assert not (tmp_path / "new" / "dataset").exists()


def _box_ply(path: Path) -> Path:
    """A 4 x 3 x 2.5 m closed box as a point map: occupied voxels only, no free space to plan a route in."""
    from hsmap.io import write_ply_points

    step = 0.05
    pts = []
    for a, b, fixed, value in ((4, 3, 2, 0.0), (4, 3, 2, 2.5), (3, 2.5, 0, 0.0), (3, 2.5, 0, 4.0),
                               (4, 2.5, 1, 0.0), (4, 2.5, 1, 3.0)):
        u, v = np.mgrid[0:a:step, 0:b:step].reshape(2, -1)
        cols = [u, v]
        cols.insert(fixed, np.full(u.size, value))
        pts.append(np.stack(cols, 1))
    write_ply_points(path, np.vstack(pts))
    return path


def test_a_failed_world_run_without_out_leaves_nothing_under_generated(tmp_path, monkeypatch, capsys):
    """Before: ``simulate --world`` made data/generated/world-NAME/ and left it empty when the route failed."""
    monkeypatch.setenv("HSMAP_GENERATED", str(tmp_path / "generated"))
    box = _box_ply(tmp_path / "box.ply")
    assert main(["simulate", "--world", str(box)]) == 2
    assert "box.ply" in capsys.readouterr().err
    assert not (tmp_path / "generated" / "world-box").exists()


# hsmap align ----------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("which", ["map2d", "map3d", "image"])
def test_align_refuses_an_output_folder_holding_its_input(tmp_path, capsys, which):
    """Before: ``hsmap align A/map2d_aligned.yaml B --out A`` replaced its own input with its output."""
    from PIL import Image

    out = tmp_path / "A"
    out.mkdir()
    img = np.full((60, 60), 254, np.uint8)
    img[10:50, 10] = img[10:50, 50] = img[10, 10:50] = img[50, 10:50] = 0
    if which == "image":  # a YAML elsewhere naming an image the outputs would replace
        Image.fromarray(img).save(out / "map3d_band.pgm")
        (tmp_path / "m.yaml").write_text(f"image: {out / 'map3d_band.pgm'}\nresolution: 0.05\norigin: [0, 0, 0]\n"
                                         "negate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n")
        inputs = [str(tmp_path / "m.yaml"), str(tmp_path / "m.yaml")]
        guarded = out / "map3d_band.pgm"
    else:
        Image.fromarray(img).save(out / "map2d_aligned.pgm")
        (out / "map2d_aligned.yaml").write_text("image: map2d_aligned.pgm\nresolution: 0.05\norigin: [0, 0, 0]\n"
                                                "negate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n")
        guarded = out / "map2d_aligned.yaml"
        inputs = [str(guarded), str(guarded)]
        if which == "map3d":
            Image.fromarray(img).save(tmp_path / "other.png")
            inputs[0] = str(tmp_path / "other.png")
    before = guarded.read_bytes()
    assert main(["align", *inputs, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "would write over the input" in err and err.count("\n") == 1
    assert guarded.read_bytes() == before


# hsmap data fetch ------------------------------------------------------------------------------------------------


@pytest.fixture
def serve_junk(tmp_path):
    """A local HTTP server whose every registry file of the octomap dataset is 5 wrong bytes: its base URL."""
    import functools
    import http.server
    import threading

    from hsmap.study.public_data import registry

    served = tmp_path / "served"
    ds = registry()["octomap"]
    for f in ds.files:
        p = served / ds.folder / f.path
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_bytes(b"junk\n")

    class Quiet(http.server.SimpleHTTPRequestHandler):
        def log_message(self, *args):
            pass

    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), functools.partial(Quiet, directory=str(served)))
    threading.Thread(target=server.serve_forever, daemon=True).start()
    yield f"http://127.0.0.1:{server.server_address[1]}"
    server.shutdown()
    server.server_close()


def test_a_refused_download_leaves_no_folder_or_lock(tmp_path, serve_junk, monkeypatch, capsys):
    """Before: the refused download left DEST/octomap/ empty and DEST/.fetch.lock."""
    monkeypatch.delenv("HSMAP_DATA_MIRROR", raising=False)
    dest = tmp_path / "dest"
    assert main(["data", "fetch", "octomap", "--mirror", serve_junk, "--dest", str(dest)]) == 2
    assert "refused" in capsys.readouterr().err
    assert not dest.exists()
    # into a folder that was there: it stays, and nothing of the refused dataset is left in it
    dest.mkdir()
    (dest / "keep.txt").write_text("mine")
    assert main(["data", "fetch", "octomap", "--mirror", serve_junk, "--dest", str(dest)]) == 2
    assert sorted(p.name for p in dest.iterdir() if p.name != ".fetch.lock") == ["keep.txt"]
