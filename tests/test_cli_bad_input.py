"""Bad inputs run as a user runs them: each gives one line ``hsmap: error: ...`` naming the file,
key, field or flag (exit 2), or the right result.

The faults (full disk, signals, two batches at once, a damaged cache) are in ``test_faults.py`` and
``test_study_datasets.py``; every reader's and parser's behaviour over generated inputs in ``test_properties.py``.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from hsmap.cli import main
from hsmap.testing import room_scan_sequence, write_scan_bag

N, STEP = 40, 0.05


def one_line(err: str) -> str:
    lines = [line for line in err.splitlines() if not line.startswith("hsmap: warning:")]
    assert len(lines) == 1 and lines[0].startswith("hsmap: error: "), err
    return lines[0][len("hsmap: error: "):]


@pytest.fixture(scope="module")
def scans():
    return room_scan_sequence(N, STEP)


def bag(folder: Path, ranges, angles, name="scans.bag", **kw) -> Path:
    kw.setdefault("angle_min", angles[0])
    kw.setdefault("angle_increment", angles[1] - angles[0])
    return write_scan_bag(folder / name, ranges, 100.0 + 0.1 * np.arange(len(ranges)), **kw)


def end_x(out: Path) -> float:
    return float((out / "trajectory.tum").read_text().splitlines()[-1].split()[1])


# 3. bad scan geometry ------------------------------------------------------------------------------------------


@pytest.mark.parametrize("field, kw", [("angle_increment", {"angle_increment": 0.0}),
                                       ("angle_increment", {"angle_increment": float("nan")}),
                                       ("range_min", {"range_min": -100.0, "negate": True})])
def test_impossible_scan_geometry_is_an_error_naming_topic_and_field(scans, tmp_path, capsys, field, kw):
    """A zero angle_increment or negative ranges (range_min -100), which would end the path in the wrong place or
    mirror it, are errors naming the topic and field."""
    r, a, _ = scans
    if kw.pop("negate", False):
        r = -r
    b = bag(tmp_path, r, a, **kw)
    assert main(["slam", str(b), "--out", str(tmp_path / "out"), "--quiet"]) == 2
    line = one_line(capsys.readouterr().err)
    assert line.startswith(f"{b}: /scan message 0 (stamp 100.000000): LaserScan {field} is "), line
    assert not (tmp_path / "out").exists()


def test_good_geometry_gives_the_right_path(scans, tmp_path, capsys):
    r, a, _ = scans
    assert main(["slam", str(bag(tmp_path, r, a)), "--out", str(tmp_path / "out"), "--quiet"]) == 0
    assert end_x(tmp_path / "out") == pytest.approx((N - 1) * STEP, abs=0.02)


# 4. one unusable scan ---------------------------------------------------------------------------------------------


def test_one_all_nan_scan_is_skipped_counted_and_named(scans, tmp_path, capsys):
    """One all-NaN scan at frame 20 of 40 is skipped, counted and named (file and cause); the other 39 frames are
    tracked."""
    r, a, _ = scans
    r = r.copy()
    r[20] = np.nan
    b = bag(tmp_path, r, a)
    out = tmp_path / "out"
    assert main(["slam", str(b), "--out", str(out), "--quiet"]) == 0
    err = capsys.readouterr().err
    assert err == (f"hsmap: warning: {b}: frame 20 (stamp 102.0) has 0 usable points (of its 541 readings, 541 are "
                   "NaN, inf or no return and 0 lie outside 0.1..30.0 m); at least 6 needed; frame skipped\n")
    m = json.loads((out / "metrics.json").read_text())
    assert m["skipped_frames"] == 1 and m["frames"] == N - 1 and m["skipped"][0]["index"] == 20
    assert end_x(out) == pytest.approx((N - 1) * STEP, abs=0.02)
    assert len((out / "trajectory.tum").read_text().splitlines()) == 1 + N - 1
    assert main(["slam", str(b), "--out", str(tmp_path / "strict"), "--quiet", "--strict"]) == 2
    assert one_line(capsys.readouterr().err).startswith(f"{b}: frame 20 (stamp 102.0) has 0 usable points")


# 5. what would be tracebacks is one line -----------------------------------------------------------------------------


def test_negative_seed_and_bad_flags(scans, tmp_path, capsys):
    r, a, _ = scans
    b = bag(tmp_path, r[:3], a)
    assert main(["slam", str(b), "--out", str(tmp_path / "o"), "--seed", "-1"]) == 2
    assert one_line(capsys.readouterr().err) == "--seed must be >= 0, got -1"
    for argv in (["slam", str(b), "--out", str(tmp_path / "o"), "--seed", "abc"], ["slam"], ["bogus"]):
        with pytest.raises(SystemExit) as exit_:
            main(argv)
        assert exit_.value.code == 2
        assert len(capsys.readouterr().err.strip().splitlines()) == 1


@pytest.mark.parametrize("command", ["slam", "segment", "reproduce", "simulate"])
def test_out_that_is_a_file(scans, tmp_path, capsys, command):
    r, a, _ = scans
    afile = tmp_path / "afile"
    afile.write_text("x")
    args = {"slam": [str(bag(tmp_path, r[:3], a))], "segment": [str(_map_png(tmp_path))],
            "reproduce": ["--only", "01"], "simulate": ["two-rooms", "--max-frames", "1"]}[command]
    assert main([command, *args, "--out", str(afile)]) == 2
    assert one_line(capsys.readouterr().err) == f"--out {afile}: exists and is not a folder"
    assert afile.read_text() == "x"


def test_map_yaml_resolution_1e308(tmp_path, capsys):
    png = _map_png(tmp_path)
    (tmp_path / "m.yaml").write_text(f"image: {png.name}\nresolution: 1e308\norigin: [0, 0, 0]\n")
    assert main(["segment", str(tmp_path / "m.yaml"), "--out", str(tmp_path / "o")]) == 2
    line = one_line(capsys.readouterr().err)
    assert line.startswith(f"{tmp_path / 'm.yaml'}: 'resolution': resolution 1e+308 m/pixel is coarser than"), line


def test_damaged_simulator_npz(tmp_path, capsys):
    ds = tmp_path / "ds"
    assert main(["simulate", "two-rooms", "--out", str(ds), "--max-frames", "3"]) == 0
    capsys.readouterr()
    with open(ds / "scans2d.npz", "r+b") as fh:
        fh.truncate(1000)
    assert main(["slam", str(ds), "--out", str(tmp_path / "o"), "--quiet"]) == 2
    assert one_line(capsys.readouterr().err).startswith(f"{ds / 'scans2d.npz'}: damaged or truncated (BadZipFile")


# 6. and 9. segment: resolution and map YAML ------------------------------------------------------------------------


def _map_png(folder: Path) -> Path:
    from PIL import Image

    img = np.zeros((120, 200), np.uint8)
    img[10:110, 10:95] = img[10:110, 105:190] = img[55:70, 95:105] = 254
    Image.fromarray(img).save(folder / "map.png")
    return folder / "map.png"


@pytest.mark.parametrize("res", ["1e-9", "1e-3"])
def test_segment_resolution_out_of_range(tmp_path, capsys, monkeypatch, res):
    """A map scale far from a floor plan's (1e-9, 1e-3 m a pixel) is refused before any segmentation work starts
    (segment_rooms checks it too): its time grows as 1/resolution, and a tiny scale gives no room."""
    import hsmap.rooms.segmentation
    from hsmap.errors import InputError
    from hsmap.maps.grid import read_map

    real = hsmap.rooms.segmentation.segment_rooms
    monkeypatch.setattr(hsmap.rooms.segmentation, "segment_rooms", lambda *a, **k: pytest.fail("segmentation started"))
    assert main(["segment", str(_map_png(tmp_path)), "--out", str(tmp_path / "o"), "--resolution", res]) == 2
    line = one_line(capsys.readouterr().err)
    assert line.startswith(f"--resolution: at resolution {float(res):g} m/pixel the map's free space covers only")
    assert not (tmp_path / "o").exists()
    grid = read_map(tmp_path / "map.png", resolution=float(res))
    with pytest.raises(InputError, match="free space covers only"):
        real(grid)


@pytest.mark.parametrize("text, key", [
    ("origin: [.nan, 0, 0]", "'origin' must be finite"),
    ("origin: [0, 0, 0]\noccupied_thresh: 1.5", "'occupied_thresh' must lie in [0, 1]"),
    ("origin: [0, 0, 0]\noccupied_thresh: 0.3\nfree_thresh: 0.6", "'free_thresh' (0.6) must be below"),
    ("origin: [0, 0, 0]\nnegate: 2", "'negate' must be 0 or 1"),
])
def test_map_yaml_fully_validated(tmp_path, capsys, text, key):
    """A map YAML is validated whole: a NaN origin (which would put NaN into doors.json and topology.json),
    thresholds out of [0, 1] and free above occupied are refused."""
    png = _map_png(tmp_path)
    (tmp_path / "m.yaml").write_text(f"image: {png.name}\nresolution: 0.05\n{text}\n")
    assert main(["segment", str(tmp_path / "m.yaml"), "--out", str(tmp_path / "o")]) == 2
    assert one_line(capsys.readouterr().err).startswith(f"{tmp_path / 'm.yaml'}: {key}")


def test_jpeg_maps_warn_and_segment_writes_valid_json(tmp_path, capsys):
    from PIL import Image

    png = _map_png(tmp_path)
    Image.open(png).save(tmp_path / "map.jpg", quality=75)
    assert main(["segment", str(tmp_path / "map.jpg"), "--out", str(tmp_path / "o")]) == 0
    assert f"hsmap: warning: {tmp_path / 'map.jpg'}: JPEG is a lossy format" in capsys.readouterr().err
    assert main(["segment", str(png), "--out", str(tmp_path / "p")]) == 0
    capsys.readouterr()
    def strict(constant):
        raise AssertionError(f"{constant} is not JSON")

    for name in ("doors.json", "topology.json"):
        json.loads((tmp_path / "p" / name).read_text(), parse_constant=strict)


# 10. evaluate relations --skip-unmatched ----------------------------------------------------------------------------


def test_relations_of_a_partial_run(scans, tmp_path, capsys):
    r, a, _ = scans
    out = tmp_path / "part"
    assert main(["slam", str(bag(tmp_path, r, a)), "--out", str(out), "--quiet", "--max-frames", "10"]) == 0
    rel = tmp_path / "run.relations"
    rel.write_text("".join(f"{100 + 0.1 * k:.6f} {100.1 + 0.1 * k:.6f} {STEP} 0 0 0 0 0\n" for k in range(N - 1)))
    assert main(["evaluate", "relations", str(out / "trajectory.tum"), str(rel)]) == 2
    assert "skip_unmatched=True (hsmap evaluate relations --skip-unmatched)" in one_line(capsys.readouterr().err)
    assert main(["evaluate", "relations", str(out / "trajectory.tum"), str(rel), "--skip-unmatched"]) == 0
    got = json.loads(capsys.readouterr().out)
    assert got["n_relations"] == 9 and got["n_skipped"] == 30 and got["translation_m"]["max"] < 0.02


# 11. harmony_icp on degenerate clouds, rng=-1 ------------------------------------------------------------------------


@pytest.mark.parametrize("cloud, what", [(np.zeros((1, 2)), "coincide"), (np.array([[0.0, 0.0], [1.0, 0.0]]),
                                         "all lie on one line"), (np.ones((100, 2)), "coincide"),
                                        (np.c_[np.random.default_rng(0).random((50, 2)), np.zeros(50)],
                                         "all lie on one plane")])
def test_harmony_icp_refuses_clouds_that_cannot_be_registered(cloud, what):
    """One point, two points or 100 identical points cannot fix a pose: an error, not an arbitrary pose."""
    from hsmap import harmony_icp
    from hsmap.errors import DegenerateInputError
    from hsmap.testing import room_cloud_3d

    good = room_cloud_3d(500, rng=0)[:, : cloud.shape[1]]
    with pytest.raises(DegenerateInputError, match=f"^source cannot be registered: .* {what}"):
        harmony_icp(cloud, good)
    with pytest.raises(DegenerateInputError, match=f"^target cannot be registered: .* {what}"):
        harmony_icp(good, cloud)


def test_harmony_icp_negative_seed():
    from hsmap import harmony_icp
    from hsmap.errors import InputError

    g = np.random.default_rng(0)
    with pytest.raises(InputError, match=r"^rng must be a seed >= 0 .*got -1$"):
        harmony_icp(g.random((50, 2)), g.random((50, 2)), rng=-1)


# 12. --prior -------------------------------------------------------------------------------------------------------


def test_prior_that_matches_no_frame_or_only_some(scans, tmp_path, capsys):
    """A --prior whose stamps match no frame is an error, not silently ignored."""
    from hsmap.testing import room_cloud_3d, sensor_cloud

    r, a, poses = scans
    world = room_cloud_3d(3000, rng=0)
    clouds = [sensor_cloud(world, np.array([p[0], p[1], 1.0, 0, 0, p[2]])) for p in poses[:8]]
    b = bag(tmp_path, r[:8], a, clouds=clouds)
    far = tmp_path / "far.tum"
    far.write_text("".join(f"{5000 + 0.1 * k:.6f} {k * STEP} 0 0 0 0 0 1\n" for k in range(8)))
    assert main(["slam", str(b), "--out", str(tmp_path / "o"), "--dof", "6", "--prior", str(far), "--quiet"]) == 2
    assert one_line(capsys.readouterr().err).startswith(
        f"--prior {far}: none of the input's 8 frames (100.000..100.700 s) lies between two of its 8 poses "
        "(5000.000..5000.700 s) within the sync tolerance of 0.1 s")
    half = tmp_path / "half.tum"
    half.write_text("".join(f"{100 + 0.1 * k:.6f} {k * STEP} 0 0 0 0 0 1\n" for k in range(4)))
    out = tmp_path / "o2"
    assert main(["slam", str(b), "--out", str(out), "--dof", "6", "--prior", str(half), "--quiet",
                 "--no-recording"]) == 0
    assert (f"hsmap: warning: --prior {half} gives a pose to 4 of the 8 frames (50.0 %) within the sync tolerance"
            in capsys.readouterr().err)
    m = json.loads((out / "metrics.json").read_text())
    assert m["prior"] == {"frames": 8, "frames_with_prior": 4, "coverage": 0.5, "sync_tolerance": 0.1}


# smaller ones ---------------------------------------------------------------------------------------------------------


def test_config_and_yaml_errors_are_one_line_naming_the_key(scans, tmp_path, capsys):
    r, a, _ = scans
    b = bag(tmp_path, r[:3], a)
    cfg = tmp_path / "c.yaml"
    cfg.write_text("max_range: abc\n")
    assert main(["slam", str(b), "--out", str(tmp_path / "o"), "--config", str(cfg)]) == 2
    assert one_line(capsys.readouterr().err) == f"{cfg}.max_range must be a number, got 'abc'"
    cfg.write_text("a: [1, 2\nb: c\n")
    assert main(["slam", str(b), "--out", str(tmp_path / "o"), "--config", str(cfg)]) == 2
    assert one_line(capsys.readouterr().err) == (f"{cfg}: not valid YAML: line 2, column 2: expected ',' or ']', but "
                                                  "got ':' (while parsing a flow sequence)")


def test_an_all_zero_quaternion_is_one_line(tmp_path, capsys):
    tum = tmp_path / "z.tum"
    tum.write_text("1 0 0 0 0 0 0 0\n2 1 0 0 0 0 0 1\n")
    assert main(["evaluate", "trajectory", str(tum), str(tum)]) == 2
    assert one_line(capsys.readouterr().err) == f"{tum}: quaternion [0.0, 0.0, 0.0, 0.0] is zero or not finite"


# the input flags and readers: each bad value is one line naming the flag or file and what was expected ------


@pytest.fixture(scope="module")
def recording_inputs(tmp_path_factory):
    """A one-second ROS2 bag (lone .mcap) of the simulated robot, and folders of KITTI clouds and 2D scans."""
    from hsmap.sim import Lidar3DConfig
    from hsmap.sim.bag import write_simulated_bag

    d = tmp_path_factory.mktemp("inputs")
    write_simulated_bag("two-rooms", d / "b.mcap", duration=1.0, lidar3d=Lidar3DConfig(channels=4, columns=16))
    cloud = np.array([[1.0, 2.0, 3.0, 1.0], [2.0, 1.0, 0.5, 1.0], [0.0, 3.0, 1.0, 1.0]], dtype="<f4")
    for name, times in [("clouds", None), ("c_count", "0.0\n0.1\n0.2\n"), ("c_nan", "0.0\nabc\n"),
                        ("c_order", "0.1\n0.0\n"), ("c_short", "0.0\n")]:
        (d / name).mkdir()
        for k in range(1 if name == "c_short" else 2):
            data = cloud.tobytes()[:10] if name == "c_short" else cloud.tobytes()
            (d / name / f"{k:06d}.bin").write_bytes(data)
        if times is not None:
            (d / name / "times.txt").write_text(times)
    (d / "scans").mkdir()
    (d / "scans" / "000000.csv").write_text("garbage\n")
    (d / "junk.mcap").write_bytes(b"not an mcap file")
    (d / "junk.db3").write_bytes(b"not a database")
    (d / "empty.mcap").write_bytes(b"")
    return d


BAD_INPUT_FLAGS = [
    # bag: flags of the base frame, the synchronisation and the offsets; flags of other inputs
    ("b.mcap", ["--base-frame", "bse_link"], "b.mcap: --base-frame bse_link: no such frame in the bag's TF"),
    ("b.mcap", ["--sync-tolerance", "-1"], "--sync-tolerance must be a number of seconds >= 0, got -1.0"),
    ("b.mcap", ["--sync-tolerance", "nan"], "--sync-tolerance must be a number of seconds >= 0, got nan"),
    ("b.mcap", ["--extrinsic2d", "0,0"], "--extrinsic2d must be 3 comma-separated finite numbers, got '0,0'"),
    ("b.mcap", ["--extrinsic2d", "a,b,c"], "--extrinsic2d must be 3 comma-separated numbers, got 'a,b,c'"),
    ("b.mcap", ["--extrinsic2d=0,0,inf"], "--extrinsic2d must be 3 comma-separated finite numbers"),
    ("b.mcap", ["--extrinsic3d", "0,0,1"], "--extrinsic3d must be 6 comma-separated finite numbers, got '0,0,1'"),
    ("b.mcap", ["--cloud-rate", "10"], "b.mcap: --cloud-rate do not apply to a ROS bag"),
    ("b.mcap", ["--scan-rate", "10"], "b.mcap: --scan-rate do not apply to a ROS bag"),
    # cloud folders: times.txt or --cloud-rate, a folder of 2D scans
    ("clouds", [], "clouds: no times.txt in the folder or beside it; give the clouds' stamps with --times FILE (one "
                   "a line, or a TUM trajectory) or their rate with --cloud-rate HZ"),
    ("clouds", ["--times", "nowhere.txt"], "--times nowhere.txt: no such file; expected the clouds' stamps"),
    ("c_count", ["--times", "c_count/times.txt", "--cloud-rate", "2"], "--times and --cloud-rate both give the "
                                                                       "clouds' stamps; give one of them"),
    ("b.mcap", ["--times", "t.txt"], "b.mcap: --times do not apply to a ROS bag"),
    ("clouds", ["--cloud-rate", "0"], "--cloud-rate must be a rate in Hz > 0, got 0.0"),
    ("clouds", ["--cloud-rate", "10", "--scan-rate", "5"], "--scan-rate needs a folder of 2D scans (--scans DIR)"),
    ("clouds", ["--cloud-rate", "10", "--scans", "nowhere"], "--scans nowhere: no such folder; expected a folder of scan files"),
    ("clouds", ["--cloud-rate", "10", "--scans", "scans"], "scans: no times.txt in the folder or beside it; give the "
                                                           "scans' rate with --scan-rate HZ"),
    ("clouds", ["--cloud-rate", "10", "--scans", "scans", "--scan-rate", "5"], "scans/000000.csv:1: expected numbers"),
    ("c_count", [], "c_count/times.txt: 3 stamps for the 2 cloud files of c_count; expected one per file"),
    ("c_nan", [], "c_nan/times.txt:2: not a number in 'abc'"),
    ("c_order", [], "c_order/times.txt: stamps must be finite and increase from line to line"),
    # (hsmap map takes a folder of clouds without --scans as a 3D-only recording, and reads its clouds)
    ("c_short", [], "c_short/000000.bin: 10 bytes is not a whole number of KITTI points (16 bytes"),
    # lone ROS2 storage files that are not bags
    ("junk.mcap", [], "junk.mcap: cannot read as a ROS1/ROS2 bag"),
    ("junk.db3", [], "junk.db3: cannot read as a ROS1/ROS2 bag"),
    ("empty.mcap", [], "empty.mcap: cannot read as a ROS1/ROS2 bag"),
]


@pytest.mark.parametrize("command", ["slam", "map"])
@pytest.mark.parametrize("name, args, message", BAD_INPUT_FLAGS, ids=[f"{n}{''.join(a)}"[:40] for n, a, _ in BAD_INPUT_FLAGS])
def test_bad_input_flags_and_readers_are_one_line_each(recording_inputs, tmp_path, capsys, monkeypatch, command, name, args, message):
    monkeypatch.chdir(recording_inputs)
    extra = ["--dof", "6"] if command == "slam" else []
    assert main([command, name, "--out", str(tmp_path / "o"), "--quiet", "--no-recording", *extra, *args]) == 2
    assert message in one_line(capsys.readouterr().err)
    out = tmp_path / "o"
    assert not out.exists() or [p.name for p in out.iterdir()] in ([], [".stages"])  # no output, no temporary
