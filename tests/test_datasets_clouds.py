"""Folders of point clouds (.pcd, .ply, KITTI .bin, .csv) as published: natural order, files that are not clouds
left out with a note, stamps from times.txt, --times (one a line or TUM) or a rate; a folder of 2D scans; the real
BALM folder."""

from __future__ import annotations

import numpy as np
import pytest

from hsmap.datasets.clouds import SOURCE_SENSOR, CloudFolderDataset, natural_key, read_points
from hsmap.datasets.open import open_dataset
from hsmap.datasets.pcd import write_pcd
from hsmap.errors import DataFormatError, DatasetError, HsmapNote, HsmapWarning, InputError

NAMES = {"cloud_rate": "--cloud-rate", "scans": "--scans", "scan_rate": "--scan-rate", "extrinsic2d": "--extrinsic2d",
         "extrinsic3d": "--extrinsic3d", "sync_tolerance": "--sync-tolerance", "times": "--times"}
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
    with pytest.raises(DatasetError, match=r"c: no times.txt in the folder or beside it; give the clouds' stamps with "
                                           r"--times FILE \(one a line, or a TUM trajectory\) or their rate with "
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
    assert code == 2 and "or their rate with --cloud-rate HZ" in err and len(err.strip().splitlines()) == 1
    code, err = run("--dof", "6", "--cloud-rate", "0")
    assert code == 2 and "--cloud-rate must be a rate in Hz > 0, got 0" in err
    code, err = run("--dof", "6", "--cloud-rate", "10", "--scans", str(tmp_path / "none"))
    assert code == 2 and "--scans " in err and "no such folder" in err
    code, err = run("--dof", "6", "--cloud-rate", "10", "--scan-topic", "/scan")
    assert code == 2 and "--scan-topic do not apply to a point-cloud folder" in err
    code, err = run("--dof", "3", "--cloud-rate", "10")
    assert code == 2 and "need a folder of them (--scans DIR)" in err
    code, err = run("--dof", "6", "--cloud-rate", "10")
    assert code == 0 and "hsmap: warning:" not in err  # clouds alone: posed in their own frame
    m = json.loads((tmp_path / "o" / "metrics.json").read_text())
    assert m["frames"] == 4 and m["input_info"]["clouds"]["stamps"] == "--cloud-rate 10"
    assert m["input_info"]["extrinsics"]["3d"]["source"] == SOURCE_SENSOR
    np.testing.assert_allclose(m["per_frame"]["stamp"], [0.0, 0.1, 0.2, 0.3])
    from hsmap.trajectory import read_tum

    np.testing.assert_allclose(read_tum(tmp_path / "o" / "trajectory.tum").poses[:, 0], [0, 0.05, 0.1, 0.15],
                               atol=0.02)


def numbered(folder, names: list[str], kind: str = ".pcd") -> dict[str, np.ndarray]:
    """One small cloud per name, each told apart by its first point's x (the name's position in ``names``)."""
    folder.mkdir(parents=True, exist_ok=True)
    clouds = {}
    for k, name in enumerate(names):
        pts = cloud(k)[[0, 2]]
        write_pcd(folder / f"{name}{kind}", pts, data="binary")
        clouds[name] = pts
    return clouds


def test_numbered_files_are_read_in_natural_order(tmp_path):
    names = [f"full{k}" for k in range(12)]
    clouds = numbered(tmp_path / "c", names[::-1])  # written in any order
    (tmp_path / "c" / "times.txt").write_text("".join(f"{100 + 0.5 * k}\n" for k in range(12)))
    ds = open_dataset(tmp_path / "c")
    frames = list(ds.frames())
    for name, f in zip(names, frames, strict=True):  # full2 before full10, each with its own stamp
        np.testing.assert_array_equal(f.cloud3d, clouds[name].astype(np.float32))
    np.testing.assert_array_equal(ds.stamps, 100 + 0.5 * np.arange(12))
    info = ds.describe()["clouds"]
    assert info["first"] == "full0.pcd" and info["last"] == "full11.pcd" and info["left_out"] == {}
    assert sorted(["scan10", "scan2", "scan1b", "scan1a", "Scan3"], key=natural_key) == [
        "Scan3", "scan1a", "scan1b", "scan2", "scan10"]
    # stamps as names, fractions of any length, by value
    assert sorted(["1630577759.5.pcd", "1630577759.25.pcd", "1630577758.75.pcd"], key=natural_key) == [
        "1630577758.75.pcd", "1630577759.25.pcd", "1630577759.5.pcd"]


def test_files_that_are_not_clouds_are_left_out_with_one_note(tmp_path):
    folder = tmp_path / "balm"
    numbered(folder, [f"full{k}" for k in range(4)])
    (folder / "alidarPose.csv").write_text("1,0,0,0,\n" * 16)  # the poses: not a cloud
    (folder / "README.md").write_text("about")
    (folder / "originals.sha256").write_text("x")
    (folder / "map.pcd").write_bytes((folder / "full0.pcd").read_bytes())  # not a numbered sweep
    (folder / ".hidden").write_text("")
    (folder / "sub").mkdir()
    with pytest.warns(HsmapNote) as caught:
        ds = open_dataset(folder, cloud_rate=2.0)
    assert len(caught) == 1 and len(ds) == 4
    note = str(caught[0].message)
    assert note == (f"{folder}: 4 files not read as clouds: README.md, originals.sha256 (not a cloud file); "
                    "alidarPose.csv (text beside the .pcd clouds); map.pcd (not named like the numbered clouds "
                    "full#.pcd)")
    assert ds.describe()["clouds"]["left_out"]["text beside the .pcd clouds"] == ["alidarPose.csv"]
    # the command line prints it as a note, one line
    import contextlib
    import io

    from hsmap.cli import main

    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        code = main(["slam", str(folder), "--out", str(tmp_path / "o"), "--dof", "6", "--times",
                     str(tmp_path / "none.txt")])
    lines = err.getvalue().splitlines()
    assert code == 2 and len(lines) == 2 and lines[0] == f"hsmap: note: {note}"
    assert lines[1] == f"hsmap: error: --times {tmp_path / 'none.txt'}: no such file; expected the clouds' stamps, " \
                        "one a line or a TUM trajectory"
    # two kinds of cloud file: still an error naming them
    write(folder, ".ply", [cloud(0)])
    with pytest.raises(DatasetError, match=r"balm: holds .pcd and .ply files; expected one kind of cloud file"):
        open_dataset(folder, cloud_rate=2.0)


def test_times_flag_takes_one_stamp_a_line_or_a_tum_trajectory(tmp_path):
    folder = tmp_path / "c"
    numbered(folder, [f"{k}" for k in range(3)], ".pcd")
    (folder / "times.txt").write_text("0\n1\n2\n")  # overridden by a stamps file given
    plain = tmp_path / "stamps.txt"
    plain.write_text("# stamps\n10.5\n11.0\n\n11.5\n")
    ds = open_dataset(folder, times=plain)
    np.testing.assert_array_equal(ds.stamps, [10.5, 11.0, 11.5])
    assert ds.describe()["clouds"]["stamps"] == str(plain) and str(plain) in ds.extra_paths
    tum = tmp_path / "groundtruth.tum"
    tum.write_text("# timestamp x y z qx qy qz qw\n" + "".join(f"{20 + k * 0.1:.6f} {k} 0 0 0 0 0 1\n"
                                                                 for k in range(3)))
    np.testing.assert_allclose(open_dataset(folder, times=tum).stamps, [20.0, 20.1, 20.2])
    bad = tmp_path / "bad.txt"
    bad.write_text("1 2 3\n")
    with pytest.raises(DataFormatError, match=r"bad.txt:1: expected one stamp a line or a TUM trajectory line"):
        open_dataset(folder, times=bad)
    with pytest.raises(InputError, match=r"--times and --cloud-rate both give the clouds' stamps; give one of them"):
        open_dataset(folder, times=plain, cloud_rate=2.0, option_names=NAMES)
    inside = folder / "stamps.tum"  # a stamps file in the folder itself is not a cloud
    inside.write_text(tum.read_text())
    np.testing.assert_allclose(open_dataset(folder, times=inside).stamps, [20.0, 20.1, 20.2])


def test_a_stamps_count_other_than_the_clouds_names_the_file_and_both_counts(tmp_path):
    import contextlib
    import io

    from hsmap.cli import main

    folder = tmp_path / "c"
    numbered(folder, [f"{k}" for k in range(3)])
    tum = tmp_path / "groundtruth.tum"
    tum.write_text("".join(f"{k}.0 0 0 0 0 0 0 1\n" for k in range(5)))
    with pytest.raises(DataFormatError, match=rf"^{tum}: 5 stamps \(a TUM trajectory\) for the 3 cloud files of "
                                              rf"{folder}; expected one per file, in natural order$"):
        open_dataset(folder, times=tum)
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        code = main(["map", str(folder), "--out", str(tmp_path / "o"), "--times", str(tum)])
    assert code == 2 and err.getvalue() == (f"hsmap: error: {tum}: 5 stamps (a TUM trajectory) for the 3 cloud "
                                            f"files of {folder}; expected one per file, in natural order\n")


def test_clouds_alone_are_posed_in_their_own_frame_without_a_warning(tmp_path):
    folder = tmp_path / "c"
    numbered(folder, ["0", "1"])
    ds = open_dataset(folder, cloud_rate=1.0)  # any warning fails this test
    assert ds.describe()["extrinsics"]["3d"] == {"value": [0.0] * 6, "source": SOURCE_SENSOR}
    ds = open_dataset(folder, cloud_rate=1.0, extrinsic3d=EXT3, option_names=NAMES)
    assert ds.describe()["extrinsics"]["3d"]["source"] == "--extrinsic3d"


@pytest.fixture
def balm():
    """The shared BALM folder as published (no times.txt); skips, saying why, where it is missing."""
    from hsmap.study.paths import datasets_dir
    from hsmap.study.public_data import dataset_folder, missing_data_reason

    folder = dataset_folder("balm", datasets_dir())
    if folder is None:
        pytest.skip(missing_data_reason(["balm"]))
    return folder


@pytest.mark.datasets
def test_the_balm_folder_reads_as_177_sweeps_in_order_with_their_stamps(balm, tmp_path):
    from hsmap.study.public_data import balm_poses, lay_out

    times, gt = lay_out("balm", balm, tmp_path)
    poses = balm_poses(balm / "alidarPose.csv")
    for stamps in (times, gt):  # the stamps one a line, and the reference trajectory's
        with pytest.warns(HsmapNote, match=r"3 files not read as clouds: README.md, originals.sha256 \(not a cloud "
                                           r"file\); alidarPose.csv \(text beside the .pcd clouds\)"):
            ds = open_dataset(balm, times=stamps, drive="cloud")
        assert len(ds) == 177 and [f.name for f in ds._clouds.files] == [f"full{k}.pcd" for k in range(177)]
        np.testing.assert_allclose(ds.stamps, poses.stamps, rtol=0, atol=2e-6)
    assert np.all(np.diff(ds.stamps) > 0)
    np.testing.assert_array_equal(np.loadtxt(times), poses.stamps)  # times.txt: the poses' stamps as written
    f = next(iter(ds.frames()))
    assert f.stamp == poses.stamps[0] and 60_000 < len(f.cloud3d) < 90_000
    np.testing.assert_array_equal(f.cloud3d, read_points(balm / "full0.pcd"))
