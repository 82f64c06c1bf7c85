"""hsmap.pipeline.cache: the one cached-folder helper (hit, miss, stale key, damaged folder, lock, atomic
publication) and the code digest that keys it (the whole core package; loud when a file it expects is missing).

The end-to-end check: in a temporary copy of the package, one simulator source file changes, and the simulated
dataset, the SLAM runs and the maps made from them are all computed again."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import pytest
from _worlds import TINY_SCENARIO

import hsmap
from hsmap.errors import CacheError, DatasetError
from hsmap.pipeline.cache import EXCLUDED, MARKER, FolderCache, code_digest

PACKAGE = Path(hsmap.__file__).resolve().parent


def copy_package(dest: Path, *, caches: bool = False) -> Path:
    """A copy of the installed package at ``dest/hsmap``: its sources, and with ``caches`` its bytecode and compiled
    kernels too (copied with their sources' times, so still valid: a run of the copy need not compile them)."""
    ignore = None if caches else shutil.ignore_patterns("__pycache__", "*.pyc")
    shutil.copytree(PACKAGE, dest / "hsmap", ignore=ignore)
    return dest / "hsmap"


def write_text(folder: Path, text: str = "result") -> None:
    (folder / "out.txt").write_text(text)


def read_text(folder: Path) -> str:
    p = folder / "out.txt"
    if not p.is_file():
        raise DatasetError(f"{p}: missing")
    return p.read_text()


# --- the code digest ---------------------------------------------------------------------------------------


def test_digest_covers_the_core_package_and_not_the_excluded_parts(tmp_path):
    root = copy_package(tmp_path)
    base = code_digest(root)
    assert base == code_digest(PACKAGE)  # a copy of the same code has the same digest
    (root / "viz" / "figures.py").write_text((root / "viz" / "figures.py").read_text() + "\n# a figure tweak\n")
    (root / "study" / "report.py").write_text((root / "study" / "report.py").read_text() + "\n# a wording\n")
    assert code_digest(root) == base  # drawing and the study layer are not part of the key
    (root / "maps" / "fusion.py").write_text((root / "maps" / "fusion.py").read_text() + "\n# an algorithm change\n")
    changed = code_digest(root)
    assert changed != base
    (root / "sim" / "new_model.py").write_text("X = 1\n")  # a new module enters the key by itself
    assert code_digest(root) not in (base, changed)
    os.rename(root / "sim" / "new_model.py", root / "sim" / "renamed_model.py")  # so does a renamed one
    assert code_digest(root) not in (base, changed)


@pytest.mark.parametrize("missing", ["__init__.py", "sim/__init__.py", *EXCLUDED])
def test_digest_fails_loudly_when_a_file_it_expects_is_missing(tmp_path, missing):
    root = copy_package(tmp_path)
    target = root / missing
    if target.is_dir():
        shutil.rmtree(target)
    else:
        target.unlink()
    with pytest.raises(CacheError, match=missing.replace(".", r"\.")):
        code_digest(root)


def test_digest_fails_loudly_on_an_unreadable_file(tmp_path, monkeypatch):
    root = copy_package(tmp_path)
    real = Path.read_bytes

    def unreadable(self):
        if self.name == "grid.py":
            raise PermissionError(13, "Permission denied", str(self))
        return real(self)

    monkeypatch.setattr(Path, "read_bytes", unreadable)
    with pytest.raises(CacheError, match=r"grid\.py: cannot read it"):
        code_digest(root)


# --- the cached folder ------------------------------------------------------------------------------------


def test_miss_then_hit_then_stale(tmp_path):
    cache = FolderCache(tmp_path)
    calls = []

    def compute(folder):
        calls.append(folder.name)
        write_text(folder, "v1")

    a = cache.get("thing", {"x": 1}, compute, read_text)
    assert (a.value, a.cached, len(calls)) == ("v1", False, 1)
    assert a.folder == tmp_path / "thing" and calls[0].startswith(".thing.tmp-")  # written beside, then renamed
    assert json.loads((a.folder / MARKER).read_text())["key"] == a.key
    b = cache.get("thing", {"x": 1}, compute, read_text)
    assert (b.value, b.cached, b.key, len(calls)) == ("v1", True, a.key, 1)
    assert cache.lookup("thing", {"x": 1}, compute, read_text).cached
    c = cache.get("thing", {"x": 2}, compute, read_text)  # another description: the slot is replaced
    assert not c.cached and c.key != a.key and len(calls) == 2
    assert cache.lookup("thing", {"x": 1}, compute, read_text) is None
    assert sorted(p.name for p in tmp_path.iterdir()) == [".locks", "thing"]  # nothing piles up


@pytest.mark.parametrize("damage", ["no_marker", "garbage_marker", "wrong_key", "missing_file", "truncated_file",
                                    "altered_file", "does_not_load"])
def test_a_damaged_folder_is_computed_again(tmp_path, damage):
    """An incomplete or stale folder is computed again quietly; a damaged one (a file missing, truncated or
    altered since it was written, or one its loader rejects) with a warning naming the file and the damage."""
    import warnings

    from hsmap.errors import HsmapWarning

    cache = FolderCache(tmp_path)
    calls = []

    def compute(folder):
        calls.append(1)
        write_text(folder)

    loads = []

    def load(folder):
        loads.append(1)
        if damage == "does_not_load" and len(loads) == 2:  # the second call reads the published folder
            raise EOFError("a loader's complaint about the file")
        return read_text(folder)

    a = cache.get("thing", {"x": 1}, compute, load)
    out = a.folder / "out.txt"
    expected = {"missing_file": f"{out} is missing", "truncated_file": f"{out} has 3 bytes, 6 were written (truncated or replaced)",
                "altered_file": f"{out} was altered since it was written (its SHA-256 differs)", "does_not_load":
                "it does not load (EOFError: a loader's complaint about the file)"}.get(damage)
    if damage == "no_marker":
        (a.folder / MARKER).unlink()
    elif damage == "garbage_marker":
        (a.folder / MARKER).write_text('{"key": ')
    elif damage == "wrong_key":
        (a.folder / MARKER).write_text(json.dumps({"key": "0" * 64}))
    elif damage == "missing_file":
        out.unlink()
    elif damage == "truncated_file":
        out.write_text("res")
    elif damage == "altered_file":
        out.write_text("RESULT")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        b = cache.get("thing", {"x": 1}, compute, load)
    assert not b.cached and len(calls) == 2 and b.value == "result"
    messages = [str(w.message) for w in caught if issubclass(w.category, HsmapWarning)]
    if expected is None:
        assert messages == []
    else:
        assert messages == [f"cache folder {a.folder} is damaged: {expected}; computing it again"]


def test_an_interrupted_computation_publishes_nothing(tmp_path):
    cache = FolderCache(tmp_path)

    def broken(folder):
        (folder / "out.txt").write_text("half")
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        cache.get("thing", {}, broken, read_text)
    assert [p.name for p in tmp_path.iterdir()] == [".locks"]
    with pytest.raises(CacheError, match="slot"):
        cache.get("../escape", {}, write_text, read_text)


def test_a_result_that_does_not_read_back_is_an_error(tmp_path):
    with pytest.raises(CacheError, match="does not read back"):
        FolderCache(tmp_path).get("thing", {}, lambda folder: None, read_text)


def test_two_threads_compute_once(tmp_path):
    cache = FolderCache(tmp_path)
    calls, results = [], []

    def slow(folder):
        calls.append(1)
        time.sleep(0.5)
        write_text(folder)

    threads = [threading.Thread(target=lambda: results.append(cache.get("t", {}, slow, read_text)))
               for _ in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(calls) == 1 and sorted(r.cached for r in results) == [False, True]


def test_lock_held_by_another_process(tmp_path):
    code = textwrap.dedent(f"""
        import time
        from hsmap.pipeline.cache import FolderCache
        with FolderCache({str(tmp_path)!r}).lock("slot"):
            print("held", flush=True)
            time.sleep(1.5)
    """)
    with subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True) as child:
        assert child.stdout.readline().strip() == "held"
        with pytest.raises(CacheError, match="still locked"):
            with FolderCache(tmp_path, lock_timeout=0.2).lock("slot"):
                pass
        t0 = time.monotonic()
        with FolderCache(tmp_path, lock_timeout=30).lock("slot"):  # waits for the child to let go
            waited = time.monotonic() - t0
        assert waited > 0.3
        child.wait(timeout=30)
    assert child.returncode == 0


# --- end to end: a simulator change recomputes the dataset, the SLAM runs and the maps ----------------------

PROBE = """
import json, sys
import hsmap, hsmap.sim.writer, hsmap.slam
from hsmap.pipeline import GridsConfig
from hsmap.study import two_lidar_maps

counts = {"simulate": 0, "run_slam": 0}
for mod, name in ((hsmap.sim.writer, "simulate"), (hsmap.slam, "run_slam")):
    real = getattr(mod, name)
    def counting(*a, _real=real, _name=name, **k):
        counts[_name] += 1
        return _real(*a, **k)
    setattr(mod, name, counting)

maps = two_lidar_maps(sys.argv[1], 2, grids=GridsConfig(slice=(0.5, 0.7)))
ds_key = json.load(open(f"{maps.dataset.path}/cache.json"))["key"]
print(json.dumps({"package": hsmap.__file__, "counts": counts, "dataset": ds_key, "maps": maps.key,
                  "maps_cached": maps.cached, "maps_folder": str(maps.folder)}))
"""


@pytest.mark.slow
def test_a_simulator_change_recomputes_the_dataset_the_slam_runs_and_the_maps(tmp_path):
    root = copy_package(tmp_path / "copy", caches=True)
    scn = tmp_path / "tiny.yaml"
    scn.write_text(TINY_SCENARIO)
    env = {**os.environ, "PYTHONPATH": str(root.parent), "HSMAP_GENERATED": str(tmp_path / "generated"),
           "RERUN_ANALYTICS": "0"}

    def probe() -> dict:
        p = subprocess.run([sys.executable, "-c", PROBE, str(scn)], capture_output=True, text=True, env=env,
                           cwd=tmp_path, timeout=600)  # not the checkout: its hsmap/ would come first
        assert p.returncode == 0, p.stderr
        return json.loads(p.stdout.strip().splitlines()[-1])

    first = probe()
    assert Path(first["package"]).resolve().parent == root  # the copy runs, not the installed package
    assert first["counts"] == {"simulate": 1, "run_slam": 2} and not first["maps_cached"]
    again = probe()  # nothing changed: everything is read back
    assert again["counts"] == {"simulate": 0, "run_slam": 0} and again["maps_cached"]
    assert (again["dataset"], again["maps"]) == (first["dataset"], first["maps"])

    sensors = root / "sim" / "sensors.py"
    sensors.write_text(sensors.read_text() + "\n# a change to the LiDAR model\n")
    after = probe()
    assert after["counts"] == {"simulate": 1, "run_slam": 2} and not after["maps_cached"]
    assert after["dataset"] != first["dataset"] and after["maps"] != first["maps"]
    assert after["maps_folder"] == first["maps_folder"]  # the same slot, replaced in place
    runs = sorted(p.name for p in (tmp_path / "generated" / "slam").iterdir() if not p.name.startswith("."))
    assert len(runs) == 2  # the 3-DOF and the 6-DOF run, replaced, not piled up
