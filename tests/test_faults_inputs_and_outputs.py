"""Bad inputs and faults run as a user runs them (configuration files, scenarios, sizes beyond the memory, cloud
files, the batch's cluster, notebook parameters, outputs, downloads, stamps, odometry): each gives one line
``hsmap: error: ...`` naming the file, key, field or flag (exit 2), a warning saying what was done, or the right
result. The property-based search over configuration files and map YAMLs is in ``test_properties.py``.
"""

from __future__ import annotations

import json
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
from _cli import error_line, run_cli


def alias_bomb(levels: int, key: str = "odometry_sigma") -> str:
    """A YAML document of a few hundred bytes whose one key's value expands to about 9**levels numbers."""
    items = ["&l0 [1, 1, 1, 1, 1, 1, 1, 1, 1]"]
    for i in range(1, levels):
        items.append(f"&l{i} [" + ", ".join([f"*l{i - 1}"] * 9) + "]")
    return f"{key}: [" + ", ".join(items) + "]\n"


# --- configuration files -------------------------------------------------------------------------------------------


@pytest.mark.parametrize("text, expected", [
    ("1: 2\n", "key 1 is not a name; SlamConfig has"),
    ("loop_closure: 5\n", "loop_closure must be a mapping of LoopClosureConfig fields"),
    ("loop_closure:\n", "loop_closure must be a mapping of LoopClosureConfig fields"),
    ("registration: [1, 2]\n", "registration must be a mapping of RegistrationConfig fields"),
    ("registration: {harmony: {memory_size: 1000000000000}}\n", "harmony.memory_size must be at most 100000"),
    ("registration: {harmony: {batch_size: 1000000000}}\n", "harmony.batch_size must be at most 100000"),
])
def test_bad_config_files_are_one_line_naming_the_file_and_key(tmp_path, text, expected):
    """A key that is not a name (``1: 2``), a section that is not a mapping (``loop_closure: 5``) and a harmony
    size beyond its bound (``memory_size: 1000000000000``) are each one line naming the file and the key."""
    cfg = tmp_path / "c.yaml"
    cfg.write_text(text)
    code, err = run_cli("slam", tmp_path / "missing", "--out", tmp_path / "o", "--config", cfg)
    assert code == 2
    line = error_line(err)
    assert line.startswith(str(cfg)) and expected in line, line


def test_yaml_1_2_numbers_are_numbers_in_configs_and_scenarios(tmp_path):
    """``1e-1`` (no dot) is a number, as YAML 1.2 reads it, in configuration files and scenarios."""
    from hsmap.config import load_config
    from hsmap.sim.scenario import load_scenario
    from hsmap.slam import SlamConfig

    cfg = tmp_path / "c.yaml"
    cfg.write_text("verify_sigmas: 3e0\nkeyframe_distance: 1e-1\n")
    c = load_config(SlamConfig, cfg)
    assert (c.verify_sigmas, c.keyframe_distance) == (3.0, 0.1)
    src = Path(__file__).parents[1] / "hsmap" / "sim" / "scenarios" / "two-rooms.yaml"
    scn = tmp_path / "s.yaml"
    scn.write_text(src.read_text().replace("\nframe_rate: 2.0\n", "\nframe_rate: 2e0\n"))
    assert load_scenario(scn, check=False).frame_rate == 2.0


def test_a_yaml_alias_bomb_is_refused_in_one_short_line(tmp_path):
    """A config of a few hundred bytes whose value expands through aliases to millions of numbers (9**7 = 4.8
    million here) is refused in one short line: the message never quotes the expanded value."""
    cfg = tmp_path / "c.yaml"
    cfg.write_text(alias_bomb(7))
    assert cfg.stat().st_size < 600
    code, err = run_cli("slam", tmp_path / "missing", "--out", tmp_path / "o", "--config", cfg)
    assert code == 2
    line = error_line(err)
    assert line.startswith(f"{cfg}: not valid YAML") and "aliases" in line, line
    small = tmp_path / "s.yaml"  # within the bound: the value is quoted, shortened
    small.write_text(alias_bomb(3))
    code, err = run_cli("slam", tmp_path / "missing", "--out", tmp_path / "o", "--config", small)
    assert code == 2 and "odometry_sigma must be 5 finite numbers" in error_line(err)


# --- scenarios and simulator folders -------------------------------------------------------------------------------


def test_a_scenario_frame_rate_is_bounded(tmp_path):
    """``frame_rate: 1e9`` is refused in one line naming the file, the key and its bound."""
    src = Path(__file__).parents[1] / "hsmap" / "sim" / "scenarios" / "two-rooms.yaml"
    scn = tmp_path / "s.yaml"
    scn.write_text(src.read_text().replace("\nframe_rate: 2.0\n", "\nframe_rate: 1000000000\n"))
    code, err = run_cli("simulate", scn, "--check")
    assert code == 2
    assert error_line(err) == f"{scn}: frame_rate: must be at most 1000 Hz (a LiDAR's scan rate), got 1e+09"


def test_a_simulator_folder_without_sensors_names_the_key(tmp_path):
    """A simulator folder whose dataset.yaml has no ``sensors`` is one line naming the file and the key."""
    from hsmap.sim.writer import simulate

    out = tmp_path / "sim"
    simulate("two-rooms", out, max_frames=2)
    meta = out / "dataset.yaml"
    lines = meta.read_text().splitlines()
    start = next(i for i, s in enumerate(lines) if s.startswith("sensors:"))
    end = next((i for i in range(start + 1, len(lines)) if lines[i] and not lines[i][0].isspace()), len(lines))
    meta.write_text("\n".join(lines[:start] + lines[end:]) + "\n")
    code, err = run_cli("slam", out, "--out", tmp_path / "o")
    assert code == 2
    assert error_line(err) == (f"{meta}: 'sensors' must be a mapping with the 'lidar2d' and 'lidar3d' "
                               f"descriptions, got None")


# --- sizes ---------------------------------------------------------------------------------------------------------


def png_header_only(path: Path, width: int, height: int) -> Path:
    """A PNG file of a few dozen bytes whose header declares ``width`` x ``height`` 8-bit gray pixels."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0))
                     + chunk(b"IDAT", zlib.compress(b"\x00" * 16)) + chunk(b"IEND", b""))
    return path


@pytest.mark.parametrize("side", [20000, 12000])
def test_huge_map_images_are_refused_before_decoding(tmp_path, monkeypatch, side):
    """A map image whose header declares more pixels than the memory allows (20000 x 20000, 12000 x 12000) is
    refused in one line from its header alone, before decoding. The memory available is set to 8 GiB so that the
    check does not depend on the machine."""
    monkeypatch.setattr("hsmap.limits.available_memory", lambda: 8 << 30)
    png = png_header_only(tmp_path / "big.png", side, side)
    code, err = run_cli("segment", png, "--out", tmp_path / "o")
    assert code == 2
    line = error_line(err)
    assert line.startswith(f"{png}: ") and (f"{side} x {side}" in line or "pixels" in line), line
    assert not (tmp_path / "o").exists()


def test_an_occupancy_grid_too_large_for_the_memory_is_refused():
    """An occupancy grid that would not fit the memory (``hsmap map --resolution 0.0001``) is refused in one line
    before it is allocated."""
    from hsmap.errors import InputError
    from hsmap.maps.grid import grid_from_scans

    scan = np.array([[30.0, 0.0], [0.0, 30.0], [-30.0, 0.0]])
    with pytest.raises(InputError, match=r"occupancy grid at 1e-05 m per cell \(the resolution\) needs .* GiB"):
        grid_from_scans([scan], np.zeros((1, 3)), 1e-5)


def test_memory_errors_are_one_line(tmp_path, monkeypatch):
    """A size no check foresees still ends in one line, not a traceback."""
    def boom(*a, **k):
        raise MemoryError()

    monkeypatch.setattr("hsmap.maps.grid.read_map", boom)
    png = png_header_only(tmp_path / "m.png", 10, 10)
    code, err = run_cli("segment", png, "--out", tmp_path / "o")
    assert code == 2 and error_line(err).startswith("segment: out of memory ("), err


# --- a slow 2D LiDAR -------------------------------------------------------------------------------------------------


def test_map_of_a_slow_2d_lidar_whose_clouds_are_not_on_its_scans(tmp_path):
    """Scans at 2 Hz, a cloud 13 ms after each: ``hsmap map`` with its defaults gives every cloud a prior pose,
    interpolated between two 2D poses 0.5 s apart (farther apart than the sync tolerance of 0.1 s)."""
    from hsmap.sim import Lidar3DConfig
    from hsmap.sim.bag import write_simulated_bag

    bag = write_simulated_bag("two-rooms", tmp_path / "b.mcap", seed=1, scan_rate=2.0, cloud_every=1,
                              cloud_offset=0.026, duration=5.0, lidar3d=Lidar3DConfig(channels=16, columns=128))
    out = tmp_path / "out"
    code, err = run_cli("map", bag.path, "--out", out, "--quiet", "--no-recording")
    assert code == 0, err
    m = json.loads((out / "metrics.json").read_text())
    prior = m["slam3d"]["prior"]
    assert prior["frames_with_prior"] == prior["frames"] == len(bag.clouds)


def test_a_prior_interpolates_over_its_own_cadence_only():
    """A stamp between two consecutive poses of the trajectory's regular cadence gets a pose, whatever the
    sync tolerance; one in a gap where poses are missing does not."""
    from hsmap.trajectory import Trajectory

    t = np.array([0.0, 0.5, 1.0, 1.5, 3.0, 3.5])  # one pose every 0.5 s, none between 1.5 and 3.0
    p = np.c_[t, np.zeros(len(t)), np.zeros(len(t))]
    poses, found = Trajectory(t, p).interpolate([0.013, 0.75, 2.0, 3.2, 4.0], 0.1)
    assert found.tolist() == [True, True, False, True, False]
    np.testing.assert_allclose(poses[:, 0], [0.013, 0.75, 3.2])


# --- point cloud files ---------------------------------------------------------------------------------------------


@pytest.fixture
def clouds(tmp_path):
    """A binary and a text PLY and PCD file of 1000 points each."""
    o3d = pytest.importorskip("open3d")
    pts = np.random.default_rng(0).normal(size=(1000, 3)) + 5.0
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    files = []
    for name, ascii_ in (("bin.ply", False), ("text.ply", True), ("bin.pcd", False), ("text.pcd", True)):
        o3d.io.write_point_cloud(str(tmp_path / name), pc, write_ascii=ascii_)
        files.append(tmp_path / name)
    return files


def test_a_truncated_cloud_file_is_named_as_damaged(clouds):
    """A PLY or PCD file (binary or text) cut in half is an error naming the file as damaged and the points its
    header declares, never fewer points or uninitialised ones."""
    from hsmap.datasets.clouds import read_points
    from hsmap.errors import DataFormatError

    for f in clouds:
        assert len(read_points(f)) == 1000
        data = f.read_bytes()
        f.write_bytes(data[: len(data) // 2])
        with pytest.raises(DataFormatError, match=rf"^{f}: damaged: its header declares 1000 points"):
            read_points(f)


def test_a_cloud_header_declaring_more_points_than_the_memory_is_refused(tmp_path, monkeypatch):
    """A small PLY whose header declares 500 million points is refused in one line saying the memory they need."""
    from hsmap.datasets.clouds import read_points
    from hsmap.errors import DataFormatError

    monkeypatch.setattr("hsmap.limits.available_memory", lambda: 8 << 30)
    f = tmp_path / "bomb.ply"
    f.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 500000000\nproperty float x\n"
                  b"property float y\nproperty float z\nend_header\n" + bytes(120))
    with pytest.raises(DataFormatError, match=rf"^{f}: 500000000 points declared in its header needs 29.8 GiB"):
        read_points(f)


# --- the batch's cluster -------------------------------------------------------------------------------------------


def test_a_scheduler_that_is_not_an_address_is_one_line():
    """``--scheduler 'not a url'`` is one line naming the flag and saying no Dask scheduler can be reached there."""
    from hsmap.errors import ConfigError
    from hsmap.study.distributed import _client

    with pytest.raises(ConfigError, match=r"^--scheduler not a url: cannot reach a Dask scheduler there \("):
        _client(None, "not a url")


def _flaky_cluster(monkeypatch, failures: int) -> list:
    """dask.distributed's LocalCluster and Client replaced: the cluster's first ``failures`` starts fail as
    distributed's own event-loop check does on a busy machine (an AssertionError). Returns the list of starts."""
    import dask.distributed

    starts = []

    class Cluster:
        def __init__(self, **kwargs):
            starts.append(kwargs)
            if len(starts) <= failures:
                raise AssertionError

    monkeypatch.setattr(dask.distributed, "LocalCluster", Cluster)
    monkeypatch.setattr(dask.distributed, "Client", lambda cluster: ("client", cluster))
    return starts


def test_a_local_cluster_whose_event_loop_starts_late_is_started_again(monkeypatch):
    from hsmap.study.distributed import LOCAL_CLUSTER_TRIES, _client

    starts = _flaky_cluster(monkeypatch, LOCAL_CLUSTER_TRIES - 1)
    client, cluster = _client(1, None)
    assert client == ("client", cluster) and len(starts) == LOCAL_CLUSTER_TRIES


def test_a_local_cluster_that_never_starts_is_one_line(monkeypatch):
    from hsmap.errors import ConfigError
    from hsmap.study.distributed import LOCAL_CLUSTER_TRIES, _client

    starts = _flaky_cluster(monkeypatch, LOCAL_CLUSTER_TRIES)
    with pytest.raises(ConfigError, match=r"^could not start a local Dask cluster: .* give --scheduler an address$"):
        _client(1, None)
    assert len(starts) == LOCAL_CLUSTER_TRIES


def test_the_local_cluster_and_its_dashboard_listen_on_loopback_only():
    """The local cluster's scheduler, workers and dashboard (which has no authentication) listen on the loopback
    address only."""
    psutil = pytest.importorskip("psutil")
    from hsmap.study.distributed import _client

    client, cluster = _client(1, None)
    try:
        listening = [c.laddr for c in psutil.Process().net_connections(kind="tcp") if c.status == psutil.CONN_LISTEN]
    finally:
        client.close()
        cluster.close()
    assert listening and all(a.ip in ("127.0.0.1", "::1") for a in listening), listening


def test_the_local_cluster_workers_keep_the_allocators_own_settings():
    """Dask's default MALLOC_TRIM_THRESHOLD_ would turn off glibc's adaptive mmap threshold in the workers (every
    large array mapped and faulted in afresh); its one-thread BLAS settings stay."""
    import os

    from hsmap.study.distributed import _client

    client, cluster = _client(1, None)
    try:
        env = next(iter(client.run(lambda: {k: os.environ.get(k) for k in ("MALLOC_TRIM_THRESHOLD_",
                                                                             "OMP_NUM_THREADS")}).values()))
    finally:
        client.close()
        cluster.close()
    assert env == {"MALLOC_TRIM_THRESHOLD_": None, "OMP_NUM_THREADS": "1"}


# --- inputs --------------------------------------------------------------------------------------------------------


def test_an_input_that_is_not_a_regular_file_is_refused(tmp_path):
    """An input that is not a regular file or a folder (a ``.bag`` linking to /dev/zero) is refused in one line
    before it is read."""
    link = tmp_path / "zero.bag"
    link.symlink_to("/dev/zero")
    code, err = run_cli("slam", link, "--out", tmp_path / "o")
    assert code == 2
    assert error_line(err) == (f"{link}: not a regular file or a folder (a link to /dev/zero); expected a "
                               "recording file or folder")


@pytest.mark.parametrize("flag, value", [("--extrinsic3d", "1e300,0,1,0,0,0"), ("--extrinsic2d", "0,0,1e300")])
def test_an_absurd_extrinsic_names_the_flag(tmp_path, flag, value):
    """A sensor offset beyond 100 m (``--extrinsic3d 1e300,...``, ``--extrinsic2d 0,0,1e300``) is one line naming
    the flag."""
    from hsmap.sim.writer import simulate

    simulate("two-rooms", tmp_path / "sim", max_frames=2)
    code, err = run_cli("slam", tmp_path / "sim", "--out", tmp_path / "o", "--dof", "6", flag, value)
    assert code == 2
    line = error_line(err)
    assert line.startswith(f"{flag}: a sensor offset of up to ") and "expected at most 100 m" in line, line


# --- notebook parameters -------------------------------------------------------------------------------------------


@pytest.mark.parametrize("key, value, expected", [
    ("sead", "3", "-p sead: no such parameter in 01-probe; they have fast, out_dir, quick, seed, step"),
    ("seed", "abc", "-p seed: 01-probe declares it int (a whole number; default 1), got 'abc'"),
    ("fast", "notabool", "-p fast: 01-probe declares it bool (true or false; default False), got 'notabool'"),
    ("step", "fast", "-p step: 01-probe declares it float (a number; default 0.5), got 'fast'"),
])
def test_notebook_parameters_are_checked_against_their_declarations(tmp_path, key, value, expected):
    """A notebook parameter that the notebook does not declare (``-p sead 3``), or a value of another type than
    its declaration (``-p fast notabool``, ``-p seed abc``), is one line naming the parameter, its notebook and
    the type declared."""
    pytest.importorskip("papermill")
    from test_study_batch import _notebook

    nbdir = tmp_path / "notebooks"
    nbdir.mkdir()
    cells = ['quick: bool = False\nout_dir: str = ""\nseed: int = 1\nfast: bool = False\nstep: float = 0.5',
             'raise SystemExit("the notebook ran")']
    (nbdir / "01-probe.ipynb").write_text(json.dumps(_notebook(cells, "Probe")), encoding="utf-8")
    code, err = run_cli("reproduce", "--notebooks", nbdir, "--out", tmp_path / "reports", "--no-verify",
                        "-p", key, value)
    assert code == 2 and error_line(err) == expected
    assert not (tmp_path / "reports").exists()


def test_notebook_parameter_values_read_yaml_1_2_numbers():
    from hsmap.study.discovery import parse_value

    assert parse_value("1e-1") == 0.1 and parse_value("abc") == "abc" and parse_value("true") is True


# --- outputs -------------------------------------------------------------------------------------------------------


def small_map(path: Path) -> Path:
    """A 120 x 80 pixel map of two rooms joined by a door, as PNG."""
    from PIL import Image

    a = np.full((80, 120), 255, np.uint8)
    a[:3], a[-3:], a[:, :3], a[:, -3:] = 0, 0, 0, 0
    a[:, 58:62] = 0
    a[35:50, 58:62] = 255
    Image.fromarray(a).save(path)
    return path


def test_an_output_folder_that_is_the_input_is_refused(tmp_path):
    """An output folder that is the input's (``hsmap map S --out S``, whose ground truth rooms.png and doors.json
    the estimates would replace; ``hsmap segment rooms.png --out .``) is refused in one line, the input left as
    it was."""
    from hsmap.sim.writer import simulate

    sim = tmp_path / "sim"
    simulate("two-rooms", sim, max_frames=2)
    before = {p.name: p.read_bytes() for p in sim.iterdir() if p.is_file()}
    code, err = run_cli("map", sim, "--out", sim)
    assert code == 2 and error_line(err) == f"--out {sim}: would write over the input {sim}; choose another output folder"
    assert {p.name: p.read_bytes() for p in sim.iterdir() if p.is_file()} == before
    png = small_map(tmp_path / "rooms.png")
    data = png.read_bytes()
    code, err = run_cli("segment", png, "--out", tmp_path)
    assert code == 2 and "would write over the input" in error_line(err) and png.read_bytes() == data


def test_a_rerun_leaves_no_output_of_the_earlier_run(tmp_path):
    """A rerun into the same --out leaves none of the earlier run's outputs that it does not write itself
    (steps.png after ``segment`` without --steps, slam.rrd after ``slam --no-recording`` of another input)."""
    png = small_map(tmp_path / "map.png")
    out = tmp_path / "seg"
    assert run_cli("segment", png, "--out", out, "--steps")[0] == 0 and (out / "steps.png").is_file()
    assert run_cli("segment", png, "--out", out)[0] == 0
    assert (out / "rooms.png").is_file() and not (out / "steps.png").exists()
    out = tmp_path / "slam"
    (out).mkdir()
    (out / "slam.rrd").write_bytes(b"an earlier run's recording")
    from hsmap.sim.writer import simulate

    simulate("two-rooms", tmp_path / "sim", max_frames=3)
    code, err = run_cli("slam", tmp_path / "sim", "--out", out, "--no-recording", "--quiet")
    assert code == 0, err
    assert (out / "trajectory.tum").is_file() and not (out / "slam.rrd").exists()


def test_an_interrupted_simulation_leaves_the_previous_dataset_as_it_was(tmp_path, monkeypatch):
    """Ctrl-C during ``hsmap simulate --out D`` leaves the dataset already in D as it was, byte for byte; a complete
    rerun replaces all of it."""
    from hsmap.datasets.simulated import SimulatedDataset

    out = tmp_path / "d"
    assert run_cli("simulate", "two-rooms", "--out", out, "--max-frames", "2", "--figures")[0] == 0
    before = {str(p.relative_to(out)): p.read_bytes() for p in out.rglob("*") if p.is_file()}

    def interrupt(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr("hsmap.sim.writer.write_tum", interrupt)  # after the scans and clouds are written
    assert run_cli("simulate", "two-rooms", "--out", out, "--max-frames", "3", "--seed", "5")[0] == 130
    assert {str(p.relative_to(out)): p.read_bytes() for p in out.rglob("*") if p.is_file()} == before
    assert len(SimulatedDataset(out)) == 2
    monkeypatch.undo()  # a complete rerun without --figures replaces everything, the old figures/ included
    assert run_cli("simulate", "two-rooms", "--out", out, "--max-frames", "3")[0] == 0
    assert len(SimulatedDataset(out)) == 3 and not (out / "figures").exists()
    assert not [p for p in out.iterdir() if p.name.startswith(".")]


# --- downloads -----------------------------------------------------------------------------------------------------


def test_a_failed_fetch_does_not_shadow_the_data_beside_the_checkout(tmp_path, monkeypatch):
    """A download folder that a failed ``hsmap data fetch`` left (its lock file, an empty dataset folder) does not
    take precedence over the data beside the checkout (``../shared/datasets``); a complete download does."""
    from hsmap.study import paths
    from hsmap.study.public_data import fetch_dir, registry

    monkeypatch.setenv("HSMAP_CACHE", str(tmp_path / "cache"))
    monkeypatch.delenv("HSMAP_DATASETS", raising=False)
    monkeypatch.setattr(paths, "repository_root", lambda: tmp_path / "repo")
    beside = tmp_path / "shared" / "datasets"
    beside.mkdir(parents=True)
    partial = fetch_dir()
    (partial / registry()["bormann"].folder).mkdir(parents=True)
    (partial / ".fetch.lock").write_text("")
    assert paths.datasets_dir() == beside.resolve()
    ds = registry()["bormann"]  # a complete download counts
    for f in ds.files:
        (partial / ds.folder / f.path).parent.mkdir(parents=True, exist_ok=True)
        (partial / ds.folder / f.path).write_bytes(b"x")
    assert paths.datasets_dir() == partial


# --- stamps --------------------------------------------------------------------------------------------------------


def _scan_bag(folder: Path, order=None, stamps=None, name="scans.bag") -> Path:
    from hsmap.testing import room_scan_sequence, write_scan_bag

    r, a, _ = room_scan_sequence(30, 0.05)
    t = 100.0 + 0.1 * np.arange(len(r)) if stamps is None else stamps
    k = np.arange(len(r)) if order is None else order
    return write_scan_bag(folder / name, r[k], t[k], angle_min=a[0], angle_increment=a[1] - a[0])


def _tum(path: Path) -> np.ndarray:
    return np.array([[float(v) for v in line.split()] for line in path.read_text().splitlines()
                     if line.strip() and not line.startswith("#")])


def test_a_bag_whose_seq_runs_backwards_is_ordered_by_stamp(tmp_path):
    """A bag whose ROS1 seq runs against its stamps has its frames ordered by stamp, with a warning saying so."""
    bag = _scan_bag(tmp_path, order=np.arange(30)[::-1])
    code, err = run_cli("slam", bag, "--out", tmp_path / "o", "--quiet", "--no-recording")
    assert code == 0, err
    assert f"hsmap: warning: {bag}: the ROS1 Header.seq of its messages runs against their stamps (29 of 29 " in err
    traj = _tum(tmp_path / "o" / "trajectory.tum")
    assert (np.diff(traj[:, 0]) > 0).all() and traj[-1, 1] == pytest.approx(29 * 0.05, abs=0.02)


def test_repeated_stamps_are_dropped_with_a_warning(tmp_path):
    """Scans sharing one stamp give one frame for that stamp and a warning, so that trajectory.tum has no
    repeated stamp (which ``hsmap evaluate`` rejects)."""
    t = 100.0 + 0.1 * np.arange(30)
    t[10:15] = t[9]
    bag = _scan_bag(tmp_path, stamps=t)
    code, err = run_cli("slam", bag, "--out", tmp_path / "o", "--quiet", "--no-recording")
    assert code == 0, err
    assert (f"hsmap: warning: {bag}: 5 of the 30 messages of /scan repeat an earlier message's stamp (first: "
            "100.900000 s); they are dropped, one frame per stamp") in err
    traj = _tum(tmp_path / "o" / "trajectory.tum")
    assert len(traj) == 25 and len(np.unique(traj[:, 0])) == 25
    code, err = run_cli("slam", _scan_bag(tmp_path, stamps=np.zeros(30), name="z.bag"), "--out", tmp_path / "z", "--quiet")
    assert "zero stamps: the recording was not stamped" in err


# --- odometry ------------------------------------------------------------------------------------------------------


def test_one_odometry_message_far_off_is_set_aside_with_a_warning(tmp_path):
    """One odometry pose 5 m off (frame 20 of a simulated run), where the scan match and the previous motion
    agree, is set aside for that frame with a warning: every frame of trajectory.tum stays within 5 cm of the
    truth."""
    from hsmap.geometry import relative
    from hsmap.sim.writer import simulate
    from hsmap.trajectory import read_tum

    sim = tmp_path / "sim"
    simulate("two-rooms", sim, seed=3, max_frames=30)
    odo = sim / "odometry.tum"
    lines = odo.read_text().splitlines()
    rows = [i for i, line in enumerate(lines) if line.strip() and not line.startswith("#")]
    v = lines[rows[20]].split()
    v[1] = str(float(v[1]) + 5.0)
    lines[rows[20]] = " ".join(v)
    odo.write_text("\n".join(lines) + "\n")
    code, err = run_cli("slam", sim, "--out", tmp_path / "o", "--quiet", "--no-recording")
    assert code == 0, err
    assert "hsmap: warning: frame 20 (stamp 10.000000): its odometry puts it 5.0" in err
    est, gt = read_tum(tmp_path / "o" / "trajectory.tum", dof=3), read_tum(sim / "groundtruth.tum", dof=3)
    e = [np.hypot(*(relative(est.poses[0], p)[:2] - relative(gt.poses[0], q)[:2]))
         for p, q in zip(est.poses, gt.poses, strict=False)]
    assert max(e) < 0.05, np.round(e, 3)
