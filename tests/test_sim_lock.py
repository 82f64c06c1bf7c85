"""ensure_dataset under parallel callers (two notebooks of ``hsmap reproduce --jobs 2``): one generates, the other
waits and reuses; a cut dataset (max_frames) is reused too."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
import yaml

from hsmap.datasets.simulated import SimulatedDataset
from hsmap.sim.catalog import resolve_scenario
from hsmap.sim.writer import ensure_dataset

pytest.importorskip("open3d")


def _small_scenario(tmp_path: Path) -> Path:
    p = tmp_path / "scn.yaml"
    data = yaml.safe_load(Path(resolve_scenario("two-rooms")).read_text())
    data["route"]["steps"] = data["route"]["steps"][:2]
    data["sensors"] = {"lidar3d": {"channels": 16, "columns": 128}}
    p.write_text(yaml.safe_dump(data))
    return p


def test_parallel_callers_generate_once(tmp_path):
    scn = _small_scenario(tmp_path)
    out = tmp_path / "ds"
    code = textwrap.dedent(f"""
        import time
        from hsmap.sim.writer import ensure_dataset
        import hsmap.sim.writer as w
        calls = []
        real = w.simulate
        def counting(*a, **k):
            calls.append(1)
            return real(*a, **k)
        w.simulate = counting
        ensure_dataset({str(scn)!r}, out={str(out)!r})
        print(len(calls), (w.Path({str(out)!r}) / "dataset.yaml").stat().st_mtime_ns)
    """)
    procs = [subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                              text=True) for _ in range(2)]
    results = []
    for p in procs:
        so, se = p.communicate(timeout=300)
        assert p.returncode == 0, se
        results.append(so.split())
    assert sorted(int(r[0]) for r in results) == [0, 1]  # exactly one of them simulated
    assert results[0][1] == results[1][1]  # and both saw the same, finished folder
    assert len(SimulatedDataset(out)) > 3
    assert (tmp_path / ".ds.lock").is_file()


def test_cut_dataset_is_reused(tmp_path):
    scn = _small_scenario(tmp_path)
    out = tmp_path / "cut"
    ensure_dataset(scn, out=out, max_frames=4)
    stamp = (out / "dataset.yaml").stat().st_mtime_ns
    ensure_dataset(scn, out=out, max_frames=4)
    assert (out / "dataset.yaml").stat().st_mtime_ns == stamp
    assert len(SimulatedDataset(out)) == 4
    ensure_dataset(scn, out=out, max_frames=3)  # another cut: regenerated
    assert len(SimulatedDataset(out)) == 3
