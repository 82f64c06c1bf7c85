"""The building benchmark on Dask (hsmap.study.buildings, hsmap.study.distributed, hsmap benchmark buildings):
the quick mode on a 2-process LocalCluster scored against a building's ground truth, a failing building recorded
while the others go on, a rerun that skips finished buildings, and a worker killed mid-run."""

from __future__ import annotations

import json
import os
import shutil
import signal
import threading
import time
from pathlib import Path

import _floorplans as fp
import pytest

from hsmap.study.buildings import run_buildings
from hsmap.study.distributed import RESULT_FILE

pytestmark = pytest.mark.slow


def _leftovers(folder: Path) -> list[str]:
    """Temporary files outside the stage caches (which sweep their own on the next run)."""
    return [str(p) for p in folder.rglob("*") if ".tmp" in p.name and ".stages" not in p.parts]


@pytest.fixture(scope="module")
def batch(tmp_path_factory):
    """One quick batch on a 2-process LocalCluster: the drawn three-room building, whose worker is killed during
    its chain stage, and a building with a broken image. Then a rerun of the finished building."""
    from dask.distributed import Client, LocalCluster

    tmp = tmp_path_factory.mktemp("buildings")
    maps = fp.write(tmp / "maps")
    fp.write(maps, name="broken")
    (maps / "broken_furnitures.png").write_bytes(b"not an image")
    out = tmp / "out"
    killed: dict[str, int] = {}
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0",
                      silence_logs=50) as cluster, Client(cluster) as client:

        def kill_during_chain():
            deadline = time.time() + 300
            while time.time() < deadline and not killed:
                for addr, keys in client.processing().items():
                    if any(str(k).startswith("tiny/chain") for k in keys):
                        time.sleep(1.0)  # well inside the stage
                        pid = client.run(os.getpid, workers=[addr])[addr]
                        os.kill(pid, signal.SIGKILL)
                        killed[addr] = pid
                        return
                time.sleep(0.2)

        watcher = threading.Thread(target=kill_during_chain, daemon=True)
        watcher.start()
        first = run_buildings(maps, out, quick=True, client=client, progress=False)
        watcher.join(5)
        stamp = (out / "tiny" / RESULT_FILE).stat().st_mtime_ns
        again = run_buildings(maps, out, quick=True, client=client, progress=False, only=["tiny"])
        # the command line on the running cluster, by its scheduler's address (how a user's cluster is used)
        from hsmap.cli import main

        cli_code = main(["benchmark", "buildings", "--maps", str(maps), "--out", str(out), "--only", "tiny",
                         "--quick", "--scheduler", cluster.scheduler_address])
        cli_results = json.loads((out / "results.json").read_text())
    return {"out": out, "first": first, "again": again, "killed": killed, "stamp": stamp, "cli_code": cli_code,
            "cli_results": cli_results}


def test_quick_mode_scores_the_rooms_against_the_ground_truth(batch):
    tiny = {b["name"]: b for b in batch["first"]["buildings"]}["tiny"]
    assert tiny["status"] == "ok", tiny
    assert tiny["rooms"] == 3 and tiny["frames"] > 20 and tiny["route_m"] > 5
    # the slice (above the furniture) finds the three rooms of the ground truth
    assert tiny["slice"]["recall"] >= 0.85 and tiny["slice"]["precision"] >= 0.85
    assert tiny["slice"]["recall_reached"] == tiny["slice"]["recall"]  # every room reached
    assert tiny["pose_error"]["2d"]["max_translation_m"] < 0.1
    assert tiny["pose_error"]["6dof"]["max_translation_m"] < 0.1
    out = batch["out"]
    saved = json.loads((out / "results.json").read_text())
    assert saved["mean"]["buildings_ok"] == 1 and saved["mean"]["slice"]["recall"] == tiny["slice"]["recall"]
    assert {"precision", "recall"} <= set(saved["mean"]["floor"])
    assert "| tiny |" in (out / "table.md").read_text()


def test_a_failing_building_is_recorded_and_the_others_go_on(batch):
    broken = {b["name"]: b for b in batch["first"]["buildings"]}["broken"]
    assert broken["status"] == "failed" and broken["stage"] == "simulate"
    assert "broken_furnitures.png" in broken["error"] and "\n" not in broken["error"]
    assert json.loads((batch["out"] / "broken" / RESULT_FILE).read_text())["status"] == "failed"


def test_a_killed_worker_costs_a_retry_and_nothing_is_half_written(batch):
    assert batch["killed"], "the chain stage was never seen running"
    out = batch["out"]
    rec = {b["name"]: b for b in batch["first"]["buildings"]}["tiny"]
    assert rec["status"] == "ok"  # the scheduler gave the stage to a worker again
    assert json.loads((out / "tiny" / RESULT_FILE).read_text())["slice"] == rec["slice"]
    assert json.loads((out / "tiny" / "chain" / "metrics.json").read_text())["slice"]["rooms"] >= 3
    assert not _leftovers(out)


def test_a_rerun_skips_finished_buildings(batch):
    assert (batch["out"] / "tiny" / RESULT_FILE).stat().st_mtime_ns == batch["stamp"]
    again = batch["again"]["buildings"]
    assert [b["name"] for b in again] == ["tiny"] and again[0]["slice"] == {
        b["name"]: b for b in batch["first"]["buildings"]}["tiny"]["slice"]


def test_command_line_runs_on_a_cluster_given_by_its_scheduler_address(batch):
    assert batch["cli_code"] == 0
    tiny = {b["name"]: b for b in batch["first"]["buildings"]}["tiny"]
    assert [b["name"] for b in batch["cli_results"]["buildings"]] == ["tiny"]
    assert batch["cli_results"]["buildings"][0]["slice"] == tiny["slice"]  # the finished building, not rerun
    assert (batch["out"] / "tiny" / RESULT_FILE).stat().st_mtime_ns == batch["stamp"]


def test_command_line_rejects_bad_flags(tmp_path, capsys):
    from hsmap.cli import main

    assert main(["benchmark", "buildings", "--out", str(tmp_path / "o"), "--maps", str(tmp_path / "none")]) == 2
    assert "--maps" in capsys.readouterr().err
    maps = fp.write(tmp_path / "maps")
    assert main(["benchmark", "buildings", "--out", str(tmp_path / "o"), "--maps", str(maps), "--only", "nope"]) == 2
    err = capsys.readouterr().err
    assert "--only nope" in err and "tiny" in err
    shutil.rmtree(tmp_path / "o", ignore_errors=True)
