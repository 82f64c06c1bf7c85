"""hsmap data fetch (hsmap.study.public_data) against a local HTTP server on 127.0.0.1 that serves the files of
$HSMAP_DATASETS (the original URLs cannot be reached from the test machine): an empty cache is filled and every
file's SHA-256 checked, a second fetch downloads nothing, a corrupted file is refused with one line naming it and
is not stored, a damaged local copy is replaced; the registry's hashes are those of the files the study uses."""

from __future__ import annotations

import functools
import hashlib
import http.server
import os
import threading
from pathlib import Path

import pytest

from hsmap.cli import main
from hsmap.errors import DatasetError, InputError
from hsmap.study import public_data
from hsmap.study.paths import datasets_dir as find_datasets
from hsmap.study.public_data import dataset_folder, fetch, fetch_dir, missing_data_reason, registry


class _Quiet(http.server.SimpleHTTPRequestHandler):
    def log_message(self, *args):  # no request lines in the test output
        pass


@pytest.fixture
def serve():
    """serve(folder) -> base URL of a local HTTP server on 127.0.0.1 serving ``folder``; stopped afterwards."""
    servers = []

    def start(folder: Path) -> str:
        handler = functools.partial(_Quiet, directory=str(folder))
        server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
        threading.Thread(target=server.serve_forever, daemon=True).start()
        servers.append(server)
        return f"http://127.0.0.1:{server.server_address[1]}"

    yield start
    for s in servers:
        s.shutdown()
        s.server_close()


@pytest.fixture
def cache(tmp_path, monkeypatch):
    """An empty user cache, no $HSMAP_DATASETS, no mirror from the environment."""
    monkeypatch.setenv("HSMAP_CACHE", str(tmp_path / "cache"))
    monkeypatch.delenv("HSMAP_DATASETS", raising=False)
    monkeypatch.delenv(public_data.MIRROR_ENV, raising=False)
    return tmp_path / "cache"


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _mirror_copy(src: Path, dst: Path, names=("bormann",)) -> Path:
    """The registry's files of ``names`` linked from ``src`` into ``dst`` (so one can be replaced)."""
    for name in names:
        ds = registry()[name]
        for f in ds.files:
            target = dst / ds.folder / f.path
            target.parent.mkdir(parents=True, exist_ok=True)
            os.symlink(src / ds.folder / f.path, target)
    return dst


def test_registry_lists_the_datasets_with_pinned_sources():
    reg = registry()
    assert list(reg) == ["freiburg", "bormann", "octomap", "balm"]
    assert len(reg["bormann"].files) == 45 and reg["bormann"].folder == "ipa_room_segmentation"
    assert {f.path for f in reg["freiburg"].files} >= {"intel/intel.orig.bag", "intel/intel.relations",
                                                         "fr079/fr079.orig.bag", "fr-clinic/fr-clinic.relations"}
    assert {f.path for f in reg["octomap"].files} == {"geb079.bt", "LICENSE.txt"}
    assert reg["octomap"].folder == "octomap"
    balm = reg["balm"]
    assert balm.folder == "balm" and balm.layout == "balm" and balm.size is None
    assert sorted(f.path for f in balm.files) == sorted(["alidarPose.csv", *(f"full{k}.pcd" for k in range(177))])
    assert balm.files[1].url == ("https://raw.githubusercontent.com/hku-mars/BALM/5dc1bf927fcb65ef17f0e687f553c234d6b"
                                 "17365/datas/benchmark_realworld/full0.pcd")
    for ds in reg.values():
        assert ds.citation and ds.licence and ds.sources
        for f in ds.files:
            # a pinned commit (40 hex digits) of a public repository, and a SHA-256
            assert f.url.startswith("https://raw.githubusercontent.com/"), f.url
            assert len(f.url.split("/")[5]) == 40, f.url
            assert len(f.sha256) == 64 and (f.size is None if ds.name == "balm" else f.size > 0)


@pytest.mark.datasets
def test_registry_hashes_are_those_of_the_study_data(datasets_dir):
    for ds in registry().values():
        if ds.name == "balm":  # the shared copy drops the originals' all-zero normals; it keeps their hashes
            folder = datasets_dir / "balm"
            if not folder.is_dir():
                continue
            listed = (folder / "originals.sha256").read_text().split()
            assert dict(zip(listed[1::2], listed[::2], strict=True)) == {f.path: f.sha256 for f in ds.files}
            assert _sha(folder / "alidarPose.csv") == next(f.sha256 for f in ds.files if f.path == "alidarPose.csv")
            continue
        for f in ds.files:
            local = datasets_dir / ds.folder / f.path
            assert local.stat().st_size == f.size, f.path
            assert _sha(local) == f.sha256, f.path


@pytest.mark.datasets
def test_fetch_fills_an_empty_cache_and_verifies_every_file(datasets_dir, cache, serve, capsys):
    url = serve(datasets_dir)
    assert not fetch_dir().exists()
    assert missing_data_reason(["freiburg", "bormann"], fetch_dir()).startswith("no data (run hsmap data fetch)")

    # (the shared balm copy is not the originals: its fetch is tested on a file set of its own)
    assert main(["data", "fetch", "freiburg", "bormann", "octomap", "--mirror", url]) == 0
    out = capsys.readouterr().out
    assert "freiburg: 10 files" in out and "bormann: 45 files" in out and "(45 downloaded, 0 already there)" in out
    for ds in registry().values():
        for f in ds.files if ds.name != "balm" else ():
            got = cache / "datasets" / ds.folder / f.path
            assert _sha(got) == f.sha256, f.path
    # found where readers look, without $HSMAP_DATASETS
    assert fetch_dir() == cache / "datasets" and find_datasets() == cache / "datasets"
    assert dataset_folder("freiburg") == cache / "datasets" / "slam2d"
    assert missing_data_reason(["freiburg", "bormann"]) == ""
    # nothing is downloaded twice; no temporary file is left behind
    (again,) = fetch(["bormann"], mirror=url)
    assert again.downloaded == () and len(again.present) == 45
    assert dataset_folder("octomap") == cache / "datasets" / "octomap"
    assert not [p for p in (cache / "datasets").rglob("*") if p.is_file() and p.name.startswith("tmp")]


@pytest.mark.datasets
def test_a_corrupted_file_is_refused_with_one_line_naming_it(datasets_dir, cache, serve, tmp_path, capsys):
    served = _mirror_copy(datasets_dir, tmp_path / "served")
    bad = served / "ipa_room_segmentation" / "NLB.png"
    data = bytearray(bad.read_bytes())
    data[100] ^= 0xFF  # one flipped byte
    bad.unlink()
    bad.write_bytes(bytes(data))
    url = serve(served)

    assert main(["data", "fetch", "bormann", "--mirror", url]) == 2
    err = capsys.readouterr().err
    assert err.startswith("hsmap: error: ipa_room_segmentation/NLB.png: refused") and err.count("\n") == 1
    assert hashlib.sha256(bytes(data)).hexdigest() in err
    assert not (cache / "datasets" / "ipa_room_segmentation" / "NLB.png").exists()  # nothing stored
    assert dataset_folder("bormann", fetch_dir()) is None

    # a damaged copy in the cache is replaced by a good download
    bad.unlink()
    os.symlink(datasets_dir / "ipa_room_segmentation" / "NLB.png", bad)
    fetch(["bormann"], mirror=url)
    local = cache / "datasets" / "ipa_room_segmentation" / "office_a.png"
    local.write_bytes(b"damaged")
    (res,) = fetch(["bormann"], mirror=url)
    assert res.replaced == ("office_a.png",) and _sha(local) == _sha(datasets_dir / "ipa_room_segmentation" /
                                                                      "office_a.png")


@pytest.mark.datasets
def test_a_missing_file_and_bad_arguments_fail_with_one_line(datasets_dir, cache, serve, tmp_path, capsys):
    served = _mirror_copy(datasets_dir, tmp_path / "served")
    (served / "ipa_room_segmentation" / "office_b.png").unlink()
    url = serve(served)
    with pytest.raises(DatasetError, match=r"^ipa_room_segmentation/office_b.png: download from http://127\.0\.0"
                                           r"\.1:\d+/ipa_room_segmentation/office_b.png failed: .*404"):
        fetch(["bormann"], mirror=url)
    with pytest.raises(InputError, match="unknown dataset 'kitti'; the public datasets are: freiburg, bormann, octomap, balm"):
        fetch(["kitti"])
    for args, words in ((["kitti"], "unknown dataset 'kitti'"), (["--mirror", "127.0.0.1:1"], "mirror must be")):
        assert main(["data", "fetch", *args]) == 2
        err = capsys.readouterr().err
        assert err.startswith("hsmap: error:") and words in err and err.count("\n") == 1


def test_hsmap_datasets_overrides_the_cache(tmp_path, monkeypatch):
    from hsmap.study.registry import registry

    cache = tmp_path / "cache" / "datasets"
    octomap = registry()["octomap"]
    for f in octomap.files:  # a complete download of one dataset (files present; not hash-checked here)
        (cache / octomap.folder / f.path).parent.mkdir(parents=True, exist_ok=True)
        (cache / octomap.folder / f.path).write_bytes(b"")
    monkeypatch.setenv("HSMAP_CACHE", str(tmp_path / "cache"))
    monkeypatch.setenv("HSMAP_DATASETS", str(tmp_path / "mine"))
    assert find_datasets() == tmp_path / "mine"
    monkeypatch.delenv("HSMAP_DATASETS")
    assert find_datasets() == cache  # the cache holds a complete dataset: it is used


@pytest.mark.slow
@pytest.mark.datasets
def test_notebook_08_is_skipped_without_the_data_and_runs_once_fetched(datasets_dir, cache, serve, tmp_path,
                                                                       monkeypatch):
    from hsmap.study.batch import run_notebooks

    repo = Path(__file__).resolve().parent.parent
    monkeypatch.setenv("HSMAP_GENERATED", str(tmp_path / "generated"))
    # the notebook's kernel is told the (empty) download folder; left to itself in this checkout it would find
    # ../shared/datasets
    params = {"datasets": str(fetch_dir()), "slam_logs": "intel"}  # one log is enough here
    out = tmp_path / "reports"
    (run,) = run_notebooks(repo / "notebooks", out, only=["08"], quick=True, parameters=params, log=None).runs
    assert run.status == "skipped", run.error
    assert run.error.startswith("no data (run hsmap data fetch): freiburg and bormann not found in ")
    assert "skipped" in (out / "index.html").read_text()

    fetch(["freiburg", "bormann"], mirror=serve(datasets_dir))
    result = run_notebooks(repo / "notebooks", out, only=["08"], quick=True, parameters=params, log=None)
    (run,) = result.runs
    assert result.ok and run.status == "ok", run.error
    m = run.metrics["metrics"]
    assert m["datasets_available"] is True and "skipped" not in run.metrics
    assert m["intel_hsslam_trans_m"] < 0.1  # HS-SLAM on the first 300 scans of the fetched intel log
    assert (out / "08-real-benchmarks" / "segmentation_pr.png").is_file()


@pytest.fixture
def octomap_source() -> Path:
    """The datasets folder holding OctoMap's geb079 (found before ``cache`` hides $HSMAP_DATASETS)."""
    from hsmap.study.paths import datasets_dir as find

    src = find()
    if dataset_folder("octomap", src) is None:
        pytest.skip(missing_data_reason(["octomap"], src))
    return src


def test_fetch_octomap_from_a_local_mirror(octomap_source, cache, serve, tmp_path, capsys):
    src = octomap_source
    url = serve(_mirror_copy(src, tmp_path / "served", names=("octomap",)))
    assert missing_data_reason(["octomap"], fetch_dir()).startswith("no data (run hsmap data fetch): octomap")
    assert main(["data", "fetch", "octomap", "--mirror", url]) == 0
    assert "octomap: 2 files" in capsys.readouterr().out
    folder = dataset_folder("octomap", fetch_dir())
    assert folder == cache / "datasets" / "octomap"
    assert _sha(folder / "geb079.bt") == "7663c2466e2fe335a27d1d592f91766c8154511e63a9615aeecdad1defb04d3b"
    assert missing_data_reason(["octomap"], fetch_dir()) == ""


def _fake_balm(served: Path, stamps: list[float]) -> tuple[dict, list[str]]:
    """A small BALM-like file set served under ``balm/``: numbered sweeps and an alidarPose.csv (4x4 poses, the
    stamp in the last cell); the registry entry of those files, hashed here."""
    import numpy as np

    from hsmap.datasets.pcd import write_pcd

    folder = served / "balm"
    folder.mkdir(parents=True)
    names = [f"full{k}.pcd" for k in range(len(stamps))]
    rng = np.random.default_rng(0)
    for name in names:
        write_pcd(folder / name, rng.normal(size=(50, 3)) + 3.0, data="binary")
    rows = []
    for k, t in enumerate(stamps):
        c, s = np.cos(0.1 * k), np.sin(0.1 * k)
        m = [[c, -s, 0, 0.5 * k], [s, c, 0, 0.0], [0, 0, 1, 0.1], [0, 0, 0, t]]
        rows += [",".join(f"{v:.6f}" for v in r) + "," for r in m]
    (folder / "alidarPose.csv").write_text("\n".join(rows) + "\n")
    return folder, ["alidarPose.csv", *names]


def test_fetch_balm_lays_it_out_as_hsmap_reads_it(cache, serve, tmp_path, monkeypatch, capsys):
    """The originals from a mirror, hash-checked, then times.txt and groundtruth.tum beside them; the folder opens
    as a recording of its sweeps in natural order with the poses' stamps."""
    import numpy as np

    from hsmap.datasets.open import open_dataset
    from hsmap.errors import HsmapNote
    from hsmap.study.registry import PublicDataset, PublicFile
    from hsmap.trajectory import read_tum

    stamps = [1630577758.56949 + 0.5 * k for k in range(12)]
    src, names = _fake_balm(tmp_path / "served", stamps)
    real = registry()["balm"]
    files = tuple(PublicFile(n, f"https://raw.githubusercontent.com/hku-mars/BALM/{'0' * 40}/{n}",
                             _sha(src / n), None) for n in names)
    fake = PublicDataset("balm", real.title, real.folder, real.citation, real.licence, real.sources, files,
                         real.layout)
    monkeypatch.setattr(public_data, "registry", lambda: {"balm": fake})
    url = serve(tmp_path / "served")

    assert main(["data", "fetch", "balm", "--mirror", url]) == 0
    out = capsys.readouterr().out
    assert "balm/times.txt: written from the originals" in out and "balm: 13 files" in out
    folder = cache / "datasets" / "balm"
    assert np.loadtxt(folder / "times.txt").tolist() == pytest.approx(stamps, abs=1e-6)
    gt = read_tum(folder / "groundtruth.tum")
    np.testing.assert_allclose(gt.poses[:, [0, 5]], [[0.5 * k, 0.1 * k] for k in range(12)], atol=1e-6)
    with pytest.warns(HsmapNote, match=r"2 files not read as clouds: groundtruth.tum \(not a cloud file\); "
                                       r"alidarPose.csv \(text beside the .pcd clouds\)"):
        ds = open_dataset(folder)  # times.txt and no other option
    assert [f.name for f in ds._clouds.files] == names[1:]  # full0, full1, ..., full10, full11
    np.testing.assert_allclose(ds.stamps, gt.stamps, rtol=0, atol=1e-6)

    # a file whose bytes differ from the list is refused and not stored
    (folder / "full10.pcd").unlink()
    (src / "full10.pcd").write_bytes(b"damaged")
    assert main(["data", "fetch", "balm", "--mirror", url]) == 2
    assert "balm/full10.pcd: refused" in capsys.readouterr().err and not (folder / "full10.pcd").exists()
