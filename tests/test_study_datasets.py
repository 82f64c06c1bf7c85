"""hsmap.study.datasets: a simulated dataset is generated once per scenario, seed and frame count, also by
parallel callers (two notebooks of ``hsmap reproduce --jobs 2``): one generates, the other waits and reuses it."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
import yaml

from hsmap.sim.catalog import resolve_scenario
from hsmap.study import simulated_dataset

pytest.importorskip("open3d")


def _small_scenario(tmp_path: Path, name: str = "scn") -> Path:
    p = tmp_path / f"{name}.yaml"
    data = yaml.safe_load(Path(resolve_scenario("two-rooms")).read_text())
    data["name"] = name
    data["route"]["steps"] = data["route"]["steps"][:2]
    data["sensors"] = {"lidar3d": {"channels": 16, "columns": 128}}
    p.write_text(yaml.safe_dump(data))
    return p


def test_parallel_callers_generate_once(tmp_path):
    scn = _small_scenario(tmp_path)
    root = tmp_path / "generated"
    code = textwrap.dedent(f"""
        import hsmap.sim.writer as w
        from hsmap.study import simulated_dataset
        calls = []
        real = w.simulate
        def counting(*a, **k):
            calls.append(1)
            return real(*a, **k)
        w.simulate = counting
        ds = simulated_dataset({str(scn)!r}, 1, root={str(root)!r})
        print(len(calls), ds.path)
    """)
    procs = [subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                              text=True) for _ in range(2)]
    results = []
    for p in procs:
        so, se = p.communicate(timeout=300)
        assert p.returncode == 0, se
        results.append(so.split())
    assert sorted(int(r[0]) for r in results) == [0, 1]  # exactly one of them simulated
    assert results[0][1] == results[1][1] == str(root / "scn-seed1")  # and both read the same, finished folder
    assert (root / ".locks" / "scn-seed1.lock").is_file()
    assert json.loads((root / "scn-seed1" / "cache.json").read_text())["description"]["seed"] == 1


def test_a_dataset_is_reused_and_a_changed_scenario_simulated_again(tmp_path):
    scn = _small_scenario(tmp_path)
    root = tmp_path / "generated"
    cut = simulated_dataset(scn, 1, max_frames=4, root=root)
    assert Path(cut.path).name == "scn-seed1-first4" and len(cut) == 4
    stamp = (Path(cut.path) / "dataset.yaml").stat().st_mtime_ns
    again = simulated_dataset(scn, 1, max_frames=4, root=root)
    assert (Path(again.path) / "dataset.yaml").stat().st_mtime_ns == stamp  # reused
    assert len(simulated_dataset(scn, 1, max_frames=3, root=root)) == 3  # another cut: its own folder
    full = simulated_dataset(scn, 1, root=root)
    np.testing.assert_array_equal(np.asarray(full.ranges2d)[:4], np.asarray(cut.ranges2d))  # the same frames
    assert simulated_dataset(scn, 1, max_frames=4, root=root).path == full.path  # the full folder serves a cut
    data = yaml.safe_load(scn.read_text())
    data["odometry"] = {"scale_error": 0.05}  # the scenario changes: its dataset is simulated again
    scn.write_text(yaml.safe_dump(data))
    changed = simulated_dataset(scn, 1, root=root)
    assert changed.path == full.path and (Path(changed.path) / "dataset.yaml").stat().st_mtime_ns != stamp
    assert not np.allclose(changed.odometry.poses, full.odometry.poses)


@pytest.mark.parametrize("damaged", ["scans2d.npz", "clouds3d/000002.npz"])
def test_a_damaged_dataset_is_simulated_again_with_a_warning_naming_the_file(tmp_path, damaged):
    """A truncated scans2d.npz (or 3D frame) in the cache is seen as not the file written: a warning names it and
    the dataset is simulated again (no later run fails with BadZipFile)."""
    from hsmap.errors import HsmapWarning

    scn = _small_scenario(tmp_path)
    root = tmp_path / "generated"
    ds = simulated_dataset(scn, 1, max_frames=4, root=root)
    path = Path(ds.path) / damaged
    size = path.stat().st_size
    with open(path, "r+b") as fh:
        fh.truncate(size // 2)
    with pytest.warns(HsmapWarning, match=f"cache folder .*scn-seed1-first4 is damaged: {path} has {size // 2} bytes, "
                                          f"{size} were written"):
        again = simulated_dataset(scn, 1, max_frames=4, root=root)
    assert path.stat().st_size == size
    np.testing.assert_array_equal(again.cloud3d(2), ds.cloud3d(2))
