"""CARMEN log reader: hand-written log lines, bad lines, and the Radish corrected logs when available."""

from __future__ import annotations

import gzip
import math
import sys

import numpy as np
import pytest

from hsmap.datasets.carmen import CarmenDataset
from hsmap.datasets.open import open_dataset
from hsmap.errors import DataFormatError, DatasetError

TAIL = "host 0.5"

LOG = f"""# CARMEN Logfile
# message formats defined: PARAM SYNC ODOM FLASER
PARAM robot_frontlaser_offset 0.1 100.0 {TAIL}
PARAM robot_front_laser_max 81.9 100.0 {TAIL}
ODOM 0.0 0.0 0.0 0 0 0 100.0 {TAIL}
FLASER 5 1.0 81.83 nan 2.0 -0.5 5.0 6.0 0.1 0.1 0.2 0.05 100.1 {TAIL}
NEFF 14.2
ODOM 0.2 0.1 0.05 0.3 0.1 0 100.15 {TAIL}
SYNC something else entirely
FLASER 5 1.0 1.1 1.2 inf 81.91 5.2 6.1 0.2 0.3 0.25 0.1 100.2 {TAIL}
"""


@pytest.fixture
def log_file(tmp_path):
    p = tmp_path / "small.log"
    p.write_text(LOG)
    return p


def test_flaser_frames(log_file):
    ds = open_dataset(log_file)
    assert isinstance(ds, CarmenDataset) and ds.message == "FLASER"
    frames = list(ds.frames())
    assert len(frames) == len(ds) == 2
    assert [f.stamp for f in frames] == [100.1, 100.2]
    # beam i at -pi/2 + i * pi / (n - 1): right to left, both ends on the axis
    np.testing.assert_allclose(frames[0].scan2d.angles, -math.pi / 2 + math.pi / 4 * np.arange(5))
    r0 = frames[0].scan2d.ranges
    np.testing.assert_array_equal(np.isnan(r0), [False, True, True, False, True])  # 81.83, nan, negative
    np.testing.assert_allclose(r0[[0, 3]], [1.0, 2.0])
    np.testing.assert_array_equal(np.isnan(frames[1].scan2d.ranges), [False, False, False, True, True])  # inf, 81.91
    assert frames[0].scan2d.range_max == pytest.approx(80.0)
    np.testing.assert_allclose(frames[0].scan2d.points()[0], [0.0, -1.0], atol=1e-12)
    # odometry is the odom triple; the x y theta triple is the logged pose
    np.testing.assert_allclose(frames[0].odometry, [0.1, 0.2, 0.05])
    np.testing.assert_allclose(ds.logged_poses.poses, [[5.0, 6.0, 0.1], [5.2, 6.1, 0.2]])
    np.testing.assert_allclose(ds.odometry.poses, [[0.1, 0.2, 0.05], [0.3, 0.25, 0.1]])
    np.testing.assert_allclose(frames[1].extrinsic2d, [0.1, 0.0, 0.0])  # PARAM robot_frontlaser_offset
    np.testing.assert_allclose(ds.odom_messages.stamps, [100.0, 100.15])
    np.testing.assert_allclose(ds.odom_messages.poses[1], [0.2, 0.1, 0.05])
    assert ds.params["robot_front_laser_max"] == "81.9"


def test_gzip_log_reads_the_same(log_file, tmp_path):
    gz = tmp_path / "small.log.gz"
    with gzip.open(gz, "wt") as fh:
        fh.write(LOG)
    a, b = list(open_dataset(log_file).frames()), list(open_dataset(gz).frames())
    for fa, fb in zip(a, b, strict=True):
        assert fa.stamp == fb.stamp
        np.testing.assert_array_equal(fa.scan2d.ranges, fb.scan2d.ranges)


def test_overrides(log_file):
    ds = CarmenDataset(log_file, laser_offset=-0.04, fov_deg=90, no_return=None)
    f = next(ds.frames())
    np.testing.assert_allclose(f.extrinsic2d, [-0.04, 0, 0])
    np.testing.assert_allclose(f.scan2d.angles[[0, -1]], [-math.pi / 4, math.pi / 4])
    # no_return=None trusts the PARAM maximum (81.9 - 0.05): 81.83 is then a reading
    assert f.scan2d.ranges[1] == pytest.approx(81.83)


def test_robotlaser1(tmp_path):
    ranges = "1.0 2.0 81.91 3.0"
    # type start fov res max_range accuracy remission_mode n ranges m rems laser(x y th) robot(x y th) tv rv fwd side turn
    line = (f"ROBOTLASER1 0 -1.5 3.0 1.0 81.9 0.01 0 4 {ranges} 0 "
            f"1.22 2.0 0.5 1.0 2.0 0.5 0.1 0.0 0.5 0.3 0.0 200.5 {TAIL}")
    p = tmp_path / "rl.clf"
    p.write_text(f"FLASER 3 1 1 1 0 0 0 0 0 0 200.0 {TAIL}\n{line}\n")
    ds = CarmenDataset(p)
    assert ds.message == "ROBOTLASER1"  # preferred over FLASER: it carries its geometry
    (f,) = list(ds.frames())
    assert f.stamp == 200.5
    np.testing.assert_allclose(f.scan2d.angles, [-1.5, -0.5, 0.5, 1.5])
    np.testing.assert_array_equal(np.isnan(f.scan2d.ranges), [False, False, True, False])
    np.testing.assert_allclose(f.odometry, [1.0, 2.0, 0.5])
    # the laser is 0.22 m along world x from the robot, which heads 0.5 rad
    np.testing.assert_allclose(f.extrinsic2d, [0.22 * math.cos(0.5) - 0.0, -0.22 * math.sin(0.5), 0.0], atol=1e-12)
    assert CarmenDataset(p, message="FLASER").message == "FLASER"


def test_robotlaser1_extrinsic_is_laser_in_robot_frame(tmp_path):
    # robot at (1, 2) heading pi/2; laser 0.22 m ahead of it -> world (1, 2.22)
    line = (f"ROBOTLASER1 0 -1.5 3.0 1.0 81.9 0.01 0 2 1.0 2.0 0 "
            f"1.0 2.22 1.5707963267948966 1.0 2.0 1.5707963267948966 0 0 0 0 0 1.0 {TAIL}")
    p = tmp_path / "rl.log"
    p.write_text(line + "\n")
    f = next(CarmenDataset(p).frames())
    np.testing.assert_allclose(f.extrinsic2d, [0.22, 0.0, 0.0], atol=1e-12)


@pytest.mark.parametrize(
    ("bad_line", "match"),
    [
        (f"FLASER 5 1.0 2.0 3.0 0 0 0 0 0 100.3 {TAIL}", r"small\.log:11: FLASER line has .* fields, expected"),
        (f"FLASER 5 1.0 2.0 3.0 4.0 5.0 0 0 0 0 0 oops 100.3 {TAIL}", r"small\.log:11: FLASER: 'oops' is not a number"),
        ("FLASER five 1.0", r"small\.log:11: FLASER: field 1 should be a count"),
        (f"ODOM 0.0 0.0 100.4 {TAIL}", r"small\.log:11: ODOM line has"),
        (f"ODOM 0.0 nan 0.0 0 0 0 100.4 {TAIL}", r"small\.log:11: ODOM: NaN or inf"),
        ("ROBOTLASER1 0 -1.5 3.0 1.0 81.9 0.01 0 40 1.0", r"small\.log:11: ROBOTLASER1 line is truncated"),
        ("PARAM lonely", r"small\.log:11: PARAM line needs"),
        ("FL@SER 3 1 2 3 0 0 0 0 0 0 100.5 host 0.5", r"small\.log:11: corrupted line: 'FL@SER'"),
        ("\x00\x17\x9c garbage", r"small\.log:11: corrupted line"),
    ],
)
def test_bad_lines_name_file_and_line(tmp_path, bad_line, match):
    p = tmp_path / "small.log"
    p.write_text(LOG + bad_line + "\n")
    with pytest.raises(DataFormatError, match=match):
        CarmenDataset(p)


def test_truncated_last_line(tmp_path):
    p = tmp_path / "small.log"
    p.write_text(LOG + "FLASER 5 1.0 2.0")  # cut mid-line, no newline
    with pytest.raises(DataFormatError, match=r":11: FLASER line has 3 fields"):
        CarmenDataset(p)


def test_truncated_gzip(tmp_path):
    big = LOG + "".join(
        f"FLASER 3 1 2 3 0 0 0 0 0 0 {300 + k}.0 {TAIL}\n" for k in range(3000)
    )
    blob = gzip.compress(big.encode())
    p = tmp_path / "cut.log.gz"
    p.write_bytes(blob[: len(blob) // 2])
    with pytest.raises(DataFormatError, match=r"cut\.log\.gz:\d+: .*(truncated|FLASER)"):
        CarmenDataset(p)


def test_missing_and_laserless_logs(tmp_path):
    with pytest.raises(DatasetError, match="no such"):
        CarmenDataset(tmp_path / "nope.log")
    p = tmp_path / "odom.log"
    p.write_text(f"ODOM 0 0 0 0 0 0 1.0 {TAIL}\n")
    with pytest.raises(DatasetError, match="no laser messages"):
        CarmenDataset(p)
    q = tmp_path / "small.log"
    q.write_text(LOG)
    with pytest.raises(DatasetError, match=r"no ROBOTLASER1 messages in the log; it has \{'FLASER': 2, 'ODOM': 2\}"):
        CarmenDataset(q, message="ROBOTLASER1")


def test_open_dataset_dispatch_errors(tmp_path, log_file, monkeypatch):
    with pytest.raises(DatasetError, match="scan_topic do not apply to a CARMEN log"):
        open_dataset(log_file, scan_topic="/scan")
    other = tmp_path / "map.png"
    other.write_bytes(b"\x89PNG")
    with pytest.raises(DatasetError, match="unknown input type '.png'"):
        open_dataset(other)
    empty = tmp_path / "folder"
    empty.mkdir()
    with pytest.raises(DatasetError, match="neither dataset.yaml"):
        open_dataset(empty)
    (empty / "dataset.yaml").write_text("name: x\n")
    monkeypatch.setitem(sys.modules, "hsmap.datasets.simulated", None)  # as if the module were missing
    with pytest.raises(DatasetError, match="hsmap.datasets.simulated is not available"):
        open_dataset(empty)


@pytest.mark.datasets
@pytest.mark.parametrize(
    ("path", "n_frames", "n_beams", "offset", "path_m"),
    [
        ("intel/intel-corrected.log.gz", 910, 180, 0.0, 499.5),
        ("fr079/freiburg-079-corrected.log.gz", 4791, 360, -0.04, 422.5),
    ],
)
def test_radish_corrected_logs(datasets_dir, path, n_frames, n_beams, offset, path_m):
    ds = open_dataset(datasets_dir / "slam2d" / path)
    assert len(ds) == n_frames and ds.message == "FLASER"
    assert np.all(np.isfinite(ds.stamps)) and np.mean(np.diff(ds.stamps) > 0) > 0.99  # intel's go back 4 times
    frames = list(ds.frames())
    assert {len(f.scan2d.ranges) for f in frames} == {n_beams}
    np.testing.assert_allclose(frames[0].extrinsic2d, [offset, 0, 0])
    allr = np.concatenate([f.scan2d.ranges for f in frames])
    assert np.nanmax(allr) < 40.0  # every 81.83 / 81.91 no-return masked
    assert 0.01 < np.isnan(allr).mean() < 0.05
    # a corrected log's poses: a smooth path (subsampled scans, no jumps) of the expected length
    steps = np.linalg.norm(np.diff(ds.logged_poses.poses[:, :2], axis=0), axis=1)
    assert ds.logged_poses.path_length() == pytest.approx(path_m, abs=0.5) and steps.max() < 1.5


def test_extrinsic_override(tmp_path):
    from hsmap.datasets.open import open_dataset
    from hsmap.errors import ShapeError

    log = tmp_path / "one.log"
    log.write_text("PARAM robot_frontlaser_offset 0.2 host 0\n"
                   "FLASER 3 1.0 2.0 3.0 0 0 0 0 0 0 10.0 host 10.0\n")
    assert open_dataset(log).extrinsic2d[0] == 0.2
    ds = open_dataset(log, extrinsic2d=[-0.04, 0.0, 0.0])
    np.testing.assert_allclose(next(ds.frames()).extrinsic2d, [-0.04, 0, 0])
    with pytest.raises(ShapeError, match="extrinsic2d must be 3 finite numbers"):
        open_dataset(log, extrinsic2d=[0.0, 1.0])
