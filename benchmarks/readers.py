"""Reader speed on the Freiburg logs: hsmap's readers against a bare rosbags loop, relations metric on odometry.

Writes reports/benchmarks/readers.json. Usage: ``HSMAP_DATASETS=../shared/datasets .venv/bin/python
benchmarks/readers.py [--repeat 3]``. Times are medians over ``--repeat`` runs in this process.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

from _report import finish, machine  # noqa: E402  (benchmarks/_report.py)

from hsmap.datasets.open import open_dataset
from hsmap.datasets.relations import read_relations
from hsmap.evaluation import relations_error

ROOT = Path(__file__).resolve().parents[1]
INPUTS = [
    ("intel", "slam2d/intel/intel.orig.bag", "slam2d/intel/intel.relations"),
    ("intel-clf2bag", "slam2d/intel/intel.clf2bag.bag", None),
    ("fr079", "slam2d/fr079/fr079.orig.bag", "slam2d/fr079/fr079.relations"),
    ("fr-clinic", "slam2d/fr-clinic/fr-clinic_robotlaser.orig.bag", "slam2d/fr-clinic/fr-clinic.relations"),
    ("intel-corrected", "slam2d/intel/intel-corrected.log.gz", None),
    ("fr079-corrected", "slam2d/fr079/freiburg-079-corrected.log.gz", None),
]


def read_all(path: Path) -> tuple[object, int]:
    ds = open_dataset(path)
    n = sum(1 for _ in ds.frames())
    return ds, n


def rosbags_loop(path: Path) -> int:
    """Peer: the plain rosbags way, deserialising every /scan and /odom message (no masking, no ordering)."""
    from rosbags.highlevel import AnyReader

    n = 0
    with AnyReader([path]) as reader:
        conns = [c for c in reader.connections if c.topic in ("/scan", "/odom")]
        for c, _, raw in reader.messages(connections=conns):
            reader.deserialize(raw, c.msgtype)
            n += 1
    return n


def timed(fn, repeat: int) -> tuple[float, list[float], object]:
    times, out = [], None
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times), times, out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--out", default=str(ROOT / "reports" / "benchmarks" / "readers.json"))
    args = ap.parse_args(argv)
    from hsmap.study.paths import datasets_dir

    data = datasets_dir()  # $HSMAP_DATASETS, else what hsmap data fetch downloaded, else ../shared/datasets
    if not data.is_dir():
        print(f"datasets folder {data} not found (run hsmap data fetch, or set HSMAP_DATASETS)", file=sys.stderr)
        return 2
    host = machine()
    results = {}
    for name, rel_path, relations in INPUTS:
        path = data / rel_path
        if not path.exists():
            continue
        med, times, (ds, n) = timed(lambda p=path: read_all(p), args.repeat)
        entry = {
            "input": rel_path,
            "frames": n,
            "read_s_median": med,
            "read_s_all": times,
            "frames_per_s": n / med,
        }
        if path.suffix == ".bag":
            pmed, ptimes, pn = timed(lambda p=path: rosbags_loop(p), args.repeat)
            entry["peer_rosbags_deserialize_s_median"] = pmed
            entry["peer_rosbags_messages"] = pn
            entry["order"] = ds.order.value
        if relations and ds.odometry is not None:
            t = time.perf_counter()
            res = relations_error(ds.odometry, read_relations(data / relations)).as_dict()
            entry["odometry_relations"] = {
                "translation_m": [res["translation_m"]["mean"], res["translation_m"]["std"]],
                "rotation_deg": [res["rotation_deg"]["mean"], res["rotation_deg"]["std"]],
                "n_relations": res["n_relations"],
                "metric_s": time.perf_counter() - t,
            }
        results[name] = entry
        print(name, {k: (round(v, 3) if isinstance(v, float) else v) for k, v in entry.items() if k != "read_s_all"})
    finish({"benchmark": "readers", "repeat": args.repeat, "machine": host, "results": results}, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
