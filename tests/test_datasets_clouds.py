"""Folders of point clouds (.pcd, .ply, KITTI .bin, .csv) with times.txt or a rate, and a folder of 2D scans."""

from __future__ import annotations

import numpy as np
import pytest

from hsmap.datasets.clouds import CloudFolderDataset, read_points
from hsmap.datasets.open import open_dataset
from hsmap.errors import DataFormatError, DatasetError, HsmapWarning, InputError

NAMES = {"cloud_rate": "--cloud-rate", "scans": "--scans", "scan_rate": "--scan-rate", "extrinsic2d": "--extrinsic2d",
         "extrinsic3d": "--extrinsic3d", "sync_tolerance": "--sync-tolerance"}
EXT3 = [-0.1, 0.0, 1.6, 0.0, 0.0, 0.0]


def cloud(k: int) -> np.ndarray:
    return np.array([[1.0 + k, 0.5, 0.2], [0.0, 0.0, 0.0], [-2.0, 1.0, 1.5 + 0.1 * k]])  # the zero: no return


def write(folder, kind: str, clouds: list[np.ndarray]) -> None:
    import open3d as o3d

    folder.mkdir(parents=True, exist_ok=True)
    for k, pts in enumerate(clouds):
        f = folder / f"{k:06d}{kind}"
        if kind == ".bin":
            np.column_stack([pts, np.ones(len(pts))]).astype("<f4").tofile(f)
        elif kind == ".csv":
            np.savetxt(f, pts, delimiter=",", header="x,y,z")
        else:
            o3d.io.write_point_cloud(str(f), o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts)),
                                     write_ascii=kind == ".ply")


@pytest.mark.parametrize("kind", [".pcd", ".ply", ".bin", ".csv"])
def test_each_kind_of_cloud_file(tmp_path, kind):
    folder = tmp_path / "velodyne"
    write(folder, kind, [cloud(k) for k in range(3)])
    (tmp_path / "times.txt").write_text("0.0\n0.1\n0.2\n")  # KITTI: beside the velodyne folder
    ds = open_dataset(folder, extrinsic3d=EXT3)
    assert isinstance(ds, CloudFolderDataset) and len(ds) == 3 and ds.driver == "cloud"
    frames = list(ds.frames())
    np.testing.assert_allclose([f.stamp for f in frames], [0.0, 0.1, 0.2])
    for k, f in enumerate(frames):
        np.testing.assert_allclose(f.cloud3d, cloud(k)[[0, 2]], atol=1e-6)  # float32 files; zeros dropped
        assert f.scan2d is None and f.odometry is None
        np.testing.assert_allclose(f.extrinsic3d, EXT3)
    info = ds.describe()
    assert info["clouds"]["kind"] == kind and info["clouds"]["files"] == 3 and info["clouds"]["rate_hz"] == pytest.approx(10)
    assert info["extrinsics"]["3d"]["source"] == "extrinsic3d" and info["warnings"] == []


def test_rate_scans_and_sync(tmp_path):
    write(tmp_path / "clouds", ".bin", [cloud(k) for k in range(4)])  # 10 Hz, no times.txt
    scans = tmp_path / "scans"
    scans.mkdir()
    for k in range(16):  # 40 Hz 2D scans: points in the 2D sensor frame, z ignored
        np.savetxt(scans / f"{k:04d}.csv", [[2.0, 0.0], [0.0, 3.0 + k], [-1.0, -1.0]])
    (scans / "times.txt").write_text("\n".join(f"{0.01 + k / 40:.4f}" for k in range(16)))
    with pytest.warns(HsmapWarning) as caught:  # no offsets given: zero, with a warning per sensor
        ds = open_dataset(tmp_path / "clouds", cloud_rate=10.0, scans=scans, option_names=NAMES)
    assert len(caught) == 2 and "--extrinsic2d X,Y,YAW" in str(caught[0].message)
    assert "--extrinsic3d X,Y,Z,ROLL,PITCH,YAW" in str(caught[1].message)
    assert ds.driver == "scan" and len(ds) == 16
    f = next(ds.frames(clouds=False))
    np.testing.assert_allclose(sorted(f.scan2d.ranges), sorted([2.0, 3.0, np.sqrt(2)]))
    np.testing.assert_allclose(f.scan2d.points()[np.argsort(f.scan2d.angles)], [[-1, -1], [2, 0], [0, 3]], atol=1e-12)
    by_cloud = ds.driven_by("cloud")
    assert len(by_cloud) == 4 and ds.driver == "scan"
    frames = list(by_cloud.frames())
    # the clouds at 0, 0.1, 0.2, 0.3 s take the nearest scans (0.01, 0.11, 0.21, 0.31 s)
    assert [round(3.0 + 4 * k) for k in range(4)] == [
        round(float(np.nanmax(f.scan2d.ranges))) for f in frames]
    info = by_cloud.describe()
    assert info["clouds"]["stamps"] == "--cloud-rate 10" and info["scans"]["stamps"].endswith("times.txt")
    assert info["extrinsics"]["2d"]["source"] == "default" and len(info["warnings"]) == 2
    tight = CloudFolderDataset(tmp_path / "clouds", cloud_rate=10.0, scans=scans, sync_tolerance=0.001,
                               drive="cloud", extrinsic2d=[0.1, 0, 0], extrinsic3d=EXT3)
    assert all(f.scan2d is None for f in tight.frames(clouds=False))


def test_bad_folders_name_the_file_and_what_was_expected(tmp_path):
    write(tmp_path / "c", ".pcd", [cloud(k) for k in range(2)])
    with pytest.raises(DatasetError, match=r"c: no times.txt in the folder or beside it; give the clouds' rate with "
                                           r"--cloud-rate HZ"):
        open_dataset(tmp_path / "c", option_names=NAMES)
    (tmp_path / "c" / "times.txt").write_text("0.0\n0.1\n0.2\n")
    with pytest.raises(DataFormatError, match=r"times.txt: 3 stamps for the 2 cloud files .* one per file"):
        open_dataset(tmp_path / "c", extrinsic3d=EXT3)
    (tmp_path / "c" / "times.txt").write_text("0.1\n0.0\n")
    with pytest.raises(DataFormatError, match="must be finite and increase"):
        open_dataset(tmp_path / "c", extrinsic3d=EXT3)
    with pytest.raises(InputError, match=r"--cloud-rate must be a rate in Hz > 0, got -5"):
        open_dataset(tmp_path / "c", cloud_rate=-5.0, option_names=NAMES)
    with pytest.raises(DatasetError, match=r"--scans .*nowhere: no such folder"):
        open_dataset(tmp_path / "c", cloud_rate=5.0, scans=tmp_path / "nowhere", option_names=NAMES)
    with pytest.raises(InputError, match=r"--scan-rate needs a folder of 2D scans \(--scans DIR\)"):
        open_dataset(tmp_path / "c", cloud_rate=5.0, scan_rate=40.0, option_names=NAMES)
    (tmp_path / "x.bag").touch()
    with pytest.raises(DatasetError, match=r"--cloud-rate do not apply to a ROS bag"):
        open_dataset(tmp_path / "x.bag", cloud_rate=5.0, option_names=NAMES)
    (tmp_path / "c" / "000009.bin").write_bytes(b"\0" * 16)
    with pytest.raises(DatasetError, match=r"holds .bin and .pcd files; expected one kind of cloud file"):
        open_dataset(tmp_path / "c", cloud_rate=5.0)
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "0.bin").write_bytes(b"\0" * 20)
    with pytest.raises(DataFormatError, match=r"0.bin: 20 bytes is not a whole number of KITTI points"):
        read_points(bad / "0.bin")
    (bad / "0.pcd").write_text("not a cloud")
    with pytest.raises(DataFormatError, match=r"0.pcd: not a PCD point cloud"):
        read_points(bad / "0.pcd")
    (bad / "0.csv").write_text("1,2,3\n1,2,x\n")
    with pytest.raises(DataFormatError, match=r"0.csv:2: expected numbers x y \[z\]"):
        read_points(bad / "0.csv")
    (bad / "1.csv").write_text("1 2 3 4\n")
    with pytest.raises(DataFormatError, match=r"1.csv:1: expected 2 or 3 numbers"):
        read_points(bad / "1.csv")
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(DatasetError, match="neither dataset.yaml .* nor point-cloud files"):
        open_dataset(empty)


def test_cli_cloud_folder_flags(tmp_path):
    """The command line names its flags; a 6-DOF run on a folder of clouds at a given rate."""
    import contextlib
    import io
    import json
    import warnings

    from hsmap.cli import main
    from hsmap.testing import room_cloud_3d

    folder = tmp_path / "clouds"
    views = [np.array([4.0 + 0.05 * k, 3.0, 1.6]) for k in range(4)]  # the sensor moves 5 cm along x per sweep
    write(folder, ".bin", [room_cloud_3d(3000, viewpoint=v, rng=k) - v for k, v in enumerate(views)])

    def run(*args):
        err = io.StringIO()
        with contextlib.redirect_stderr(err), warnings.catch_warnings():
            warnings.simplefilter("always")
            code = main(["slam", str(folder), "--out", str(tmp_path / "o"), "--quiet", "--no-recording", *args])
        return code, err.getvalue()

    code, err = run("--dof", "6")
    assert code == 2 and "give the clouds' rate with --cloud-rate HZ" in err and len(err.strip().splitlines()) == 1
    code, err = run("--dof", "6", "--cloud-rate", "0")
    assert code == 2 and "--cloud-rate must be a rate in Hz > 0, got 0" in err
    code, err = run("--dof", "6", "--cloud-rate", "10", "--scans", str(tmp_path / "none"))
    assert code == 2 and "--scans " in err and "no such folder" in err
    code, err = run("--dof", "6", "--cloud-rate", "10", "--scan-topic", "/scan")
    assert code == 2 and "--scan-topic do not apply to a point-cloud folder" in err
    code, err = run("--dof", "3", "--cloud-rate", "10")
    assert code == 2 and "need a folder of them (--scans DIR)" in err
    code, err = run("--dof", "6", "--cloud-rate", "10")
    assert code == 0 and err.count("hsmap: warning:") == 1 and "--extrinsic3d" in err
    m = json.loads((tmp_path / "o" / "metrics.json").read_text())
    assert m["frames"] == 4 and m["input_info"]["clouds"]["stamps"] == "--cloud-rate 10"
    np.testing.assert_allclose(m["per_frame"]["stamp"], [0.0, 0.1, 0.2, 0.3])
    from hsmap.trajectory import read_tum

    np.testing.assert_allclose(read_tum(tmp_path / "o" / "trajectory.tum").poses[:, 0], [0, 0.05, 0.1, 0.15],
                               atol=0.02)
