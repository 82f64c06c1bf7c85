"""Property-based tests (hypothesis) of every reader and parser, and of harmony_icp's inputs.

Each test generates inputs, well-formed ones and damaged ones (a token replaced by junk, NaN or inf, a token or
a line dropped or doubled, the file cut short, bytes that are not text, keys of the wrong kind, impossible
geometry), and checks one property: the input either reads back as the values it holds, or raises an
:class:`~hsmap.errors.HsmapError` whose message is one line naming the file (or the argument); never another
exception, and never a warning other than hsmap's own. Example counts are bounded and generation is
derandomised (the same inputs on every run, no example database): the tests are deterministic and together
take well under a minute.
"""

from __future__ import annotations

import math
import struct
import tempfile
import warnings
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hsmap.errors import HsmapError, HsmapWarning

PROFILE = dict(deadline=None, derandomize=True, database=None,
               suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large, HealthCheck.filter_too_much])

NAN, INF = float("nan"), float("inf")
JUNK = ["nan", "NaN", "inf", "-inf", "abc", "1e999", "-1e999", "0x1F", "1,5", "--1", "1e-400", "-0", "3.5.1",
        "\x00", "ü", "1e308", "-5", "0", "", "[", "]:", "{a: 1}", "!!python/object:os.system", "'", "#"]


# --- helpers ---------------------------------------------------------------------------------------------------


def outcome(fn, *names):
    """``fn()``'s value, or the HsmapError it raised after checking that its message is one line naming one of
    ``names``. Any other exception (and, under the suite's filterwarnings=error, any warning but hsmap's own)
    fails the test."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", HsmapWarning)
        try:
            return fn()
        except HsmapError as exc:
            msg = str(exc)
            assert "\n" not in msg, f"{type(exc).__name__} on several lines: {msg!r}"
            assert any(str(n) in msg for n in names), f"{type(exc).__name__} names none of {names}: {msg}"
            return exc


def tmpdir() -> Path:
    return Path(tempfile.mkdtemp(prefix="hsmap-prop-"))


@st.composite
def damage(draw, text: str) -> tuple[bytes, bool]:
    """``text`` with up to three kinds of damage (returns the bytes and whether any was done)."""
    lines = [line.split(" ") for line in text.splitlines()]
    n = draw(st.integers(0, 3))
    cut = None
    for _ in range(n):
        kind = draw(st.sampled_from(["junk", "drop", "double", "drop_line", "double_line", "cut", "blank",
                                     "comment"]))
        if not lines:
            break
        i = draw(st.integers(0, len(lines) - 1))
        line = lines[i]
        j = draw(st.integers(0, max(len(line) - 1, 0)))
        if kind == "junk" and line:
            line[j] = draw(st.sampled_from(JUNK))
        elif kind == "drop" and line:
            del line[j]
        elif kind == "double" and line:
            line.insert(j, line[j])
        elif kind == "drop_line":
            del lines[i]
        elif kind == "double_line":
            lines.insert(i, list(line))
        elif kind == "blank":
            lines.insert(i, [""])
        elif kind == "comment":
            lines.insert(i, ["#", "a", "comment"])
        elif kind == "cut":
            cut = draw(st.floats(0.0, 1.0))
    data = "\n".join(" ".join(line) for line in lines).encode("utf-8") + b"\n"
    if cut is not None:
        data = data[: int(len(data) * cut)]
    if draw(st.integers(0, 9)) == 0:  # bytes that are not text
        k = draw(st.integers(0, len(data)))
        data = data[:k] + b"\xff\xfe\x80" + data[k:]
        n += 1
    return data, n > 0


def fmt(v: float) -> str:
    return repr(float(v))


finite = st.floats(-1e3, 1e3, allow_nan=False, allow_infinity=False)
angle = st.floats(-math.pi, math.pi, allow_nan=False)


# --- TUM trajectories and Freiburg relations -------------------------------------------------------------------


def unit_quaternion():
    return st.tuples(finite, finite, finite, finite).filter(lambda q: 1e-3 < np.linalg.norm(q) < 1e6)


@settings(max_examples=80, **PROFILE)
@given(rows=st.lists(st.tuples(st.floats(0, 1e9, allow_nan=False), finite, finite, finite, unit_quaternion()),
                     min_size=1, max_size=6),
       sep=st.sampled_from([" ", "\t", ", ", "  "]), data=st.data())
def test_tum_files_read_back_or_name_the_file(rows, sep, data):
    from hsmap.geometry import quaternion_to_matrix
    from hsmap.trajectory import read_tum

    text = "# timestamp x y z qx qy qz qw\n" + "".join(
        sep.join(fmt(v) for v in (t, x, y, z, *q)) + "\n" for t, x, y, z, q in rows)
    raw, damaged = data.draw(damage(text.replace(sep, " ") if sep != " " else text))
    path = tmpdir() / "traj.tum"
    path.write_bytes(raw if damaged else text.encode())
    got = outcome(lambda: read_tum(path), path)
    if damaged or isinstance(got, HsmapError):
        assert damaged, f"a well-formed file was rejected: {got}"
        return
    a = np.array([[t, x, y, z] for t, x, y, z, _ in rows])
    np.testing.assert_array_equal(got.stamps, a[:, 0])
    np.testing.assert_array_equal(got.poses[:, :3], a[:, 1:])
    from hsmap.geometry import euler_to_matrix

    R = euler_to_matrix(got.poses[:, 3], got.poses[:, 4], got.poses[:, 5])
    np.testing.assert_allclose(R, quaternion_to_matrix(np.array([q for *_, q in rows])), atol=1e-9)


@settings(max_examples=60, **PROFILE)
@given(rows=st.lists(st.tuples(st.floats(0, 1e9, allow_nan=False), st.floats(0, 1e9, allow_nan=False), finite,
                               finite, finite, angle, angle, angle), min_size=1, max_size=6), data=st.data())
def test_relations_files_read_back_or_name_the_file(rows, data):
    from hsmap.datasets.relations import read_relations

    text = "".join(" ".join(fmt(v) for v in row) + "\n" for row in rows)
    raw, damaged = data.draw(damage(text))
    path = tmpdir() / "log.relations"
    path.write_bytes(raw)
    got = outcome(lambda: read_relations(path), path)
    if isinstance(got, HsmapError):
        assert damaged, f"a well-formed file was rejected: {got}"
        return
    if not damaged:
        a = np.array(rows)
        np.testing.assert_array_equal(got.t_i, a[:, 0])
        np.testing.assert_array_equal(got.t_j, a[:, 1])
        np.testing.assert_array_equal(got.poses, a[:, 2:])


# --- CARMEN logs -------------------------------------------------------------------------------------------------

reading = st.one_of(st.floats(0.0, 90.0), st.sampled_from([NAN, INF, -1.0, 81.83, 80.0, 0.0]))


@st.composite
def carmen_log(draw):
    """A CARMEN log of FLASER or ROBOTLASER1 lines (and ODOM, PARAM), and what it holds."""
    kind = draw(st.sampled_from(["FLASER", "ROBOTLASER1"]))
    n_frames = draw(st.integers(1, 4))
    lines, frames = [], []
    fov = draw(st.sampled_from([None, 180.0, 100.0]))
    max_range = draw(st.sampled_from([None, 81.9, 30.0]))
    if fov is not None:
        lines.append(f"PARAM laser_front_laser_fov {fmt(fov)}")
    if max_range is not None:
        lines.append(f"PARAM robot_front_laser_max {fmt(max_range)}")
    n = draw(st.integers(1, 10))
    start, res = draw(st.floats(-3.0, 0.0)), draw(st.floats(0.001, 0.3))
    line_max = draw(st.floats(1.0, 100.0))
    for k in range(n_frames):
        r = draw(st.lists(reading, min_size=n, max_size=n))
        pose, odom = draw(st.tuples(finite, finite, angle)), draw(st.tuples(finite, finite, angle))
        t = 1000.0 + k + draw(st.floats(0, 0.5))
        if kind == "FLASER":
            lines.append(f"FLASER {n} {' '.join(map(fmt, r))} {' '.join(map(fmt, pose))} {' '.join(map(fmt, odom))} "
                         f"{fmt(t)} host {fmt(t)}")
        else:
            lines.append(f"ROBOTLASER1 0 {fmt(start)} {fmt(res * (n - 1))} {fmt(res)} {fmt(line_max)} 0.01 0 {n} "
                         f"{' '.join(map(fmt, r))} 0 {' '.join(map(fmt, odom))} {' '.join(map(fmt, odom))} "
                         f"0 0 0 0 0 {fmt(t)} host {fmt(t)}")
        if draw(st.booleans()):
            lines.append(f"ODOM {' '.join(map(fmt, odom))} 0 0 0 {fmt(t)} host {fmt(t)}")
        frames.append((t, np.array(r), np.array(odom)))
    if kind == "FLASER":
        fov_r = math.radians(fov if fov is not None else 180.0)
        angles = -fov_r / 2 + (fov_r / (n - 1) * np.arange(n) if n > 1 else np.zeros(n))
        thr = min((max_range - 0.05) if max_range else INF, 80.0)
    else:
        angles = start + res * np.arange(n)
        thr = min(line_max - 0.05, 80.0)
    return "\n".join(lines) + "\n", kind, frames, angles, thr


@settings(max_examples=80, **PROFILE)
@given(log=carmen_log(), gz=st.booleans(), data=st.data())
def test_carmen_logs_read_back_or_name_the_file(log, gz, data):
    import gzip

    from hsmap.datasets.carmen import CarmenDataset

    text, kind, frames, angles, thr = log
    raw, damaged = data.draw(damage(text))
    path = tmpdir() / ("run.log.gz" if gz else "run.log")
    path.write_bytes(gzip.compress(raw, mtime=0) if gz else raw)

    def read():
        ds = CarmenDataset(path)
        return ds, list(ds.frames())

    got = outcome(read, path)
    if isinstance(got, HsmapError):
        assert damaged, f"a well-formed log was rejected: {got}"
        return
    if damaged:
        return
    ds, got_frames = got
    assert ds.message == kind and len(got_frames) == len(frames)
    for f, (t, r, odom) in zip(got_frames, frames, strict=True):
        assert f.stamp == t
        np.testing.assert_allclose(f.odometry, odom)
        valid = np.isfinite(r) & (r >= 0) & (r < thr)
        np.testing.assert_array_equal(np.isfinite(f.scan2d.ranges), valid)
        np.testing.assert_array_equal(f.scan2d.ranges[valid], r[valid])
        np.testing.assert_allclose(f.scan2d.angles, angles, atol=1e-9)


# --- map_server YAML and map images ---------------------------------------------------------------------------


@st.composite
def map_image(draw, folder: Path):
    """A small map image file (PNG, PGM, 16-bit PNG, RGB, a damaged or non-image file) and its pixels."""
    from PIL import Image

    h, w = draw(st.integers(1, 12)), draw(st.integers(1, 12))
    img = np.array(draw(st.lists(st.sampled_from([0, 255]), min_size=h * w, max_size=h * w)),
                   dtype=np.uint8).reshape(h, w)
    kind = draw(st.sampled_from(["png", "pgm", "png16", "rgb", "truncated", "garbage", "missing"]))
    path = folder / {"pgm": "map.pgm"}.get(kind, "map.png")
    if kind in ("png", "truncated"):
        Image.fromarray(img).save(path)
        if kind == "truncated":
            b = path.read_bytes()
            path.write_bytes(b[: draw(st.integers(0, len(b) - 1))])
    elif kind == "pgm":
        Image.fromarray(img).save(path, format="PPM")
    elif kind == "png16":
        Image.fromarray(img.astype(np.uint16) * 257).save(path)
    elif kind == "rgb":
        Image.fromarray(np.stack([img] * 3, -1)).save(path)
    elif kind == "garbage":
        path.write_bytes(draw(st.binary(max_size=64)))
    return path, img, {"truncated": None}.get(kind, kind in ("png", "pgm", "png16", "rgb"))  # None: may read


def yaml_value(good):
    return st.one_of(good, st.sampled_from([None, "abc", True, [], {}, [1, 2], NAN, INF, -1.0, 0.0, 1e308]))


@settings(max_examples=100, **PROFILE)
@given(data=st.data())
def test_map_yaml_and_images_read_back_or_name_the_file(data):
    from hsmap.maps.grid import FREE, OCCUPIED, read_map

    folder = tmpdir()
    image, img, readable = data.draw(map_image(folder))
    good = {
        "image": image.name,
        "resolution": data.draw(st.floats(1e-4, 10.0)),
        "origin": data.draw(st.lists(finite, min_size=2, max_size=2)) + data.draw(st.sampled_from([[], [0.0]])),
        "negate": data.draw(st.sampled_from([0, 1])),
        "occupied_thresh": data.draw(st.floats(0.5, 0.99)),
        "free_thresh": data.draw(st.floats(0.01, 0.49)),
    }
    meta = dict(good)
    bad = data.draw(st.lists(st.sampled_from(sorted(good) + ["mode"]), max_size=2, unique=True))
    for key in bad:
        meta[key] = data.draw(yaml_value(st.just(good.get(key, "trinary"))))
    if data.draw(st.integers(0, 9)) == 0:
        del meta[data.draw(st.sampled_from(sorted(meta)))]
    path = folder / "map.yaml"
    as_text = data.draw(st.booleans())  # 1e-3 without a dot is a string to YAML 1.1: map_server reads a number
    text = yaml.safe_dump(meta) if not as_text else yaml.safe_dump(
        {k: (repr(v) if isinstance(v, float) and k == "resolution" else v) for k, v in meta.items()})
    path.write_text(text)
    target = data.draw(st.sampled_from([path, image]))
    got = outcome(lambda: read_map(target), target, image)
    same = all(meta.get(k) == good[k] for k in good) and "mode" not in meta
    if isinstance(got, HsmapError):
        assert not (readable and (target == image or same)), f"a well-formed map was rejected: {got}"
        return
    assert readable is not False, "a file that is not an image was read as a map"
    assert got.data.shape == img.shape  # a cut-off PNG that still reads (only its end chunk lost) reads right
    if target == path and same:
        assert got.geometry.resolution == pytest.approx(good["resolution"])
        assert got.geometry.origin == (good["origin"][0], good["origin"][1])
        occupied, free = (img == 0, img == 255) if good["negate"] == 0 else (img == 255, img == 0)
        assert (got.data[occupied] == OCCUPIED).all() and (got.data[free] == FREE).all()
    elif target == image:
        assert (got.data[img == 255] == FREE).all() and (got.data[img == 0] == OCCUPIED).all()


# --- ROS bags: LaserScan and PointCloud2 messages written with rosbags -----------------------------------------

geometry_value = st.one_of(st.floats(-10.0, 10.0), st.sampled_from([0.0, NAN, INF, -INF, 1e-9, 1e9, -100.0]))


def _scan_geometry_ok(amin, inc, rmin, rmax, n) -> bool:
    """What can be right, decided apart from the reader: finite start, a non-zero step within a full turn,
    ranges never negative, a maximum above the minimum."""
    return (math.isfinite(amin) and math.isfinite(inc) and inc != 0 and (n < 2 or abs(inc) * (n - 1) <= 2 * math.pi
            + 1e-3) and math.isfinite(rmin) and rmin >= 0 and not math.isnan(rmax) and rmax > rmin)


@settings(max_examples=80, **PROFILE)
@given(amin=geometry_value, inc=st.one_of(st.floats(-0.1, 0.1), st.sampled_from([0.0, NAN, INF, 1.0, -2.0])),
       rmin=st.one_of(st.floats(0.0, 1.0), st.sampled_from([-100.0, -0.1, NAN, INF])),
       rmax=st.one_of(st.floats(1.0, 100.0), st.sampled_from([NAN, INF, 0.0, -1.0])),
       ranges=st.lists(st.lists(st.one_of(st.floats(-5.0, 120.0, width=32), st.sampled_from([NAN, INF, -INF])),
                                min_size=4, max_size=4), min_size=1, max_size=3),
       ros2=st.booleans())
def test_laserscan_messages_read_back_or_name_the_bag(amin, inc, rmin, rmax, ranges, ros2):
    from hsmap.datasets.rosbag import RosbagDataset, no_return_threshold
    from hsmap.testing import write_scan_bag

    r = np.asarray(ranges, dtype=np.float32)
    path = tmpdir() / ("bag" if ros2 else "scans.bag")
    write_scan_bag(path, r, 100.0 + 0.1 * np.arange(len(r)), angle_min=amin, angle_increment=inc,
                   range_min=rmin, range_max=rmax, ros2=ros2)

    def read():
        ds = RosbagDataset(path)
        return list(ds.frames())

    got = outcome(read, path)
    a32, i32, n32, x32 = (float(np.float32(v)) for v in (amin, inc, rmin, rmax))
    ok = _scan_geometry_ok(a32, i32, n32, x32, r.shape[1])
    if isinstance(got, HsmapError):
        assert not ok, f"a well-formed bag was rejected: {got}"
        assert "LaserScan" in str(got) and "/scan" in str(got)
        return
    assert ok, "impossible scan geometry was accepted"
    thr = no_return_threshold(x32)
    for f, rk in zip(got, r.astype(float), strict=True):
        np.testing.assert_allclose(f.scan2d.angles, a32 + i32 * np.arange(len(rk)))
        valid = np.isfinite(rk) & (rk >= n32) & (rk < thr)
        np.testing.assert_array_equal(np.isfinite(f.scan2d.ranges), valid)
        np.testing.assert_array_equal(f.scan2d.ranges[valid], rk[valid])


_PF_FORMATS = {1: "b", 2: "B", 3: "h", 4: "H", 5: "i", 6: "I", 7: "f", 8: "d"}


@st.composite
def pointcloud2(draw):
    """Fields, layout and data of a PointCloud2 message, well-formed or not."""
    names = draw(st.sampled_from([("x", "y", "z"), ("x", "y", "z", "intensity"), ("x", "y"), ("y", "z", "x")]))
    fields, offset = [], 0
    for name in names:
        dtype = draw(st.sampled_from([7, 7, 8, 1, 2, 3, 4, 5, 6, 0, 9]))
        size = struct.calcsize(_PF_FORMATS.get(dtype, "B"))
        fields.append((name, offset, dtype))
        offset += size + draw(st.sampled_from([0, 0, 4]))
    step = offset + draw(st.sampled_from([0, 0, 4, -2]))
    width, height = draw(st.integers(0, 5)), draw(st.integers(0, 3))
    row_step = width * step + draw(st.sampled_from([0, 0, 8, -4]))
    big = draw(st.booleans())
    size = max(row_step * max(height - 1, 0) + width * step, 0) + draw(st.sampled_from([0, 0, 3, -5]))
    data = draw(st.binary(min_size=max(size, 0), max_size=max(size, 0)))
    return fields, step, width, height, row_step, big, data


def _decode(fields, step, width, height, row_step, big, data):
    """The finite (x, y, z) points of a layout but (0, 0, 0) (no return, as Ouster sends it), decoded point by
    point with struct (None: no decodable cloud)."""
    f = {n: (o, t) for n, o, t in fields}
    if any(n not in f or f[n][1] not in _PF_FORMATS for n in "xyz") or step <= 0:
        return None
    if max(f[n][0] + struct.calcsize(_PF_FORMATS[f[n][1]]) for n in "xyz") > step:
        return None
    rs = row_step if row_step > 0 else width * step
    if len(data) < rs * (height - 1) + width * step:
        return None
    pts = []
    for r in range(height):
        for i in range(width):
            base = r * rs + i * step
            p = [struct.unpack_from((">" if big else "<") + _PF_FORMATS[f[n][1]], data, base + f[n][0])[0]
                 for n in "xyz"]
            if all(math.isfinite(v) for v in p) and any(v != 0.0 for v in p):
                pts.append(p)
    return np.array(pts, dtype=float).reshape(-1, 3)


@settings(max_examples=80, **PROFILE)
@given(cloud=pointcloud2(), ros2=st.booleans())
def test_pointcloud2_messages_read_back_or_name_the_bag(cloud, ros2):
    from rosbags.typesys import Stores, get_typestore

    from hsmap.datasets.rosbag import RosbagDataset

    fields, step, width, height, row_step, big, data = cloud
    ts = get_typestore(Stores.ROS2_HUMBLE if ros2 else Stores.ROS1_NOETIC)
    T = ts.types
    header = (T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=100, nanosec=0), frame_id="lidar")
              if ros2 else T["std_msgs/msg/Header"](seq=0, stamp=T["builtin_interfaces/msg/Time"](sec=100, nanosec=0),
                                                     frame_id="lidar"))
    msg = T["sensor_msgs/msg/PointCloud2"](
        header=header, height=height, width=width, is_bigendian=big, point_step=max(step, 0),
        row_step=max(row_step, 0), data=np.frombuffer(data, dtype=np.uint8), is_dense=False,
        fields=[T["sensor_msgs/msg/PointField"](name=n, offset=o, datatype=t, count=1) for n, o, t in fields])
    path = tmpdir() / ("bag" if ros2 else "cloud.bag")
    if ros2:
        from rosbags.rosbag2 import Writer

        writer, serialize = Writer(path, version=9), ts.serialize_cdr
    else:
        from rosbags.rosbag1 import Writer

        writer, serialize = Writer(path), ts.serialize_ros1
    with writer as w:
        c = w.add_connection("/points", "sensor_msgs/msg/PointCloud2", typestore=ts)
        w.write(c, 100_000_000_000, serialize(msg, "sensor_msgs/msg/PointCloud2"))

    got = outcome(lambda: [f.cloud3d for f in RosbagDataset(path).frames()], path)
    expected = _decode(fields, max(step, 0), width, height, max(row_step, 0), big, data)
    if isinstance(got, HsmapError):
        assert expected is None or height * width == 0 and expected.size == 0, f"a decodable cloud was rejected: {got}"
        return
    assert expected is not None, "an undecodable cloud was accepted"
    np.testing.assert_array_equal(got[0], expected)


# --- scenario YAML and configuration YAML ----------------------------------------------------------------------

_SCENARIO = {
    "name": "prop", "frame_rate": 2.0, "wall_thickness": 0.2, "door_width": 0.9,
    "walls": [{"name": "s", "from": [0, 0], "to": [6, 0]}, {"name": "e", "from": [6, 0], "to": [6, 5]},
              {"name": "n", "from": [6, 5], "to": [0, 5]}, {"name": "w", "from": [0, 5], "to": [0, 0]}],
    "doors": [{"name": "d", "center": [6, 2.5]}],
    "rooms": [{"name": "r", "rect": [0, 0, 6, 5]}],
    "furniture": [{"type": "table", "center": [3, 3.5], "size": [1.0, 0.6]}],
    "route": {"start": [1, 1, 0], "steps": [[4, 1], {"turn": 90}, [4, 2]]},
    "sensors": {"lidar3d": {"channels": 8, "columns": 64}},
}


def _paths(obj, prefix=()):
    out = [prefix] if prefix else []
    if isinstance(obj, dict):
        for k, v in obj.items():
            out += _paths(v, (*prefix, k))
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            out += _paths(v, (*prefix, i))
    return out


@settings(max_examples=60, **PROFILE)
@given(data=st.data())
def test_scenario_yaml_loads_or_names_the_file(data):
    import copy

    from hsmap.sim.scenario import load_scenario

    scn = copy.deepcopy(_SCENARIO)
    changes = data.draw(st.integers(0, 3))
    for _ in range(changes):
        where = data.draw(st.sampled_from(_paths(scn)))
        parent = scn
        for k in where[:-1]:
            parent = parent[k]
        what = data.draw(st.sampled_from(["junk", "delete", "unknown"]))
        if what == "delete":
            del parent[where[-1]]
        elif what == "unknown" and isinstance(parent, dict):
            parent["bogus_key"] = 1
        else:
            parent[where[-1]] = data.draw(st.sampled_from([None, "abc", True, -1, 0, 1e9, NAN, INF, [], {}, [1],
                                                            [NAN, 0], "1e-3"]))
    path = tmpdir() / "scn.yaml"
    text = yaml.safe_dump(scn)
    raw, damaged = data.draw(damage(text)) if data.draw(st.integers(0, 4)) == 0 else (text.encode(), False)
    path.write_bytes(raw)
    got = outcome(lambda: load_scenario(path), path)
    if isinstance(got, HsmapError):
        assert changes or damaged, f"the base scenario was rejected: {got}"
    elif not (changes or damaged):
        assert got.name == "prop" and len(got.walls) == 4


def _config_values(cls):
    from hsmap.config import to_dict

    return to_dict(cls())


@settings(max_examples=80, **PROFILE)
@given(which=st.sampled_from(["slam", "segmentation", "registration"]), data=st.data())
def test_config_yaml_loads_or_names_the_file_and_key(which, data):
    from hsmap.config import load_config, to_dict
    from hsmap.registration.icp import RegistrationConfig
    from hsmap.rooms.segmentation import SegmentationConfig
    from hsmap.slam import SlamConfig

    cls = {"slam": SlamConfig, "segmentation": SegmentationConfig, "registration": RegistrationConfig}[which]

    def leaves(d, prefix=()):
        for k, v in d.items():
            yield from (leaves(v, (*prefix, k)) if isinstance(v, dict) else [((*prefix, k), v)])

    defaults = dict(leaves(_config_values(cls)))  # nested sections too: slam.registration.harmony.hmcr, ...
    chosen = data.draw(st.lists(st.sampled_from(sorted(defaults)), max_size=3, unique=True))
    doc, given_values, certain = {}, {}, True  # certain: every value is the default, the file must load
    for key in chosen:
        v = defaults[key]
        if isinstance(v, float) and data.draw(st.booleans()):
            value = v * data.draw(st.floats(0.5, 2.0))  # a plausible change
            certain = False
        else:
            value = data.draw(st.sampled_from([None, "abc", True, -1, 0, -1.5, 1e300, NAN, [], {}, [1, 2], v]))
            certain = certain and value == v and type(value) is type(v)
        node = doc
        for k in key[:-1]:
            node = node.setdefault(k, {})
        node[key[-1]] = value
        given_values[key] = value
    if data.draw(st.integers(0, 5)) == 0:
        doc["no_such_key"] = 1
        certain = False
    path = tmpdir() / "config.yaml"
    path.write_text(yaml.safe_dump(doc))
    got = outcome(lambda: load_config(cls, path), path)
    if isinstance(got, HsmapError):
        assert not certain, f"a valid configuration was rejected: {got}"
        return
    back = dict(leaves(to_dict(got)))
    for key, v in given_values.items():  # what is accepted is kept as it was given (NaN is never accepted)
        assert back[key] == pytest.approx(v), (key, v, back[key])


# --- harmony_icp's inputs ---------------------------------------------------------------------------------------

_ARGS = ("source", "target", "bounds", "initial_guesses", "rng", "config", "field")


@st.composite
def cloud(draw, d):
    """A point cloud of dimension ``d``: mostly a real scan or room cloud, else points that cannot be registered
    (identical, on one line, too few), NaN/inf values, huge or tiny coordinates, an empty or a malformed array."""
    kind = draw(st.sampled_from(["room"] * 6 + ["random", "identical", "line", "few", "junk_values", "huge", "tiny",
                                                "empty", "malformed"]))
    g = np.random.default_rng(draw(st.integers(0, 2**16)))
    n = draw(st.integers(1, 60))
    if kind == "room":
        from hsmap.testing import raycast_2d, room_cloud_3d, room_segments

        if d == 2:
            r, a = raycast_2d(room_segments(), np.array([4.0, 3.0, draw(angle)]), beams=181)
            pts = np.column_stack([r * np.cos(a), r * np.sin(a)])
        else:
            pts = room_cloud_3d(300, rng=g)
        return pts + g.normal(0, 0.01, pts.shape) * draw(st.sampled_from([0, 1]))
    if kind == "random":
        return g.normal(size=(n, d))
    if kind == "identical":
        return np.tile(g.normal(size=d), (n, 1))
    if kind == "line":
        return g.normal(size=(n, 1)) * g.normal(size=d) + g.normal(size=d)
    if kind == "few":
        return g.normal(size=(draw(st.integers(1, d)), d))
    if kind == "junk_values":
        pts = g.normal(size=(n, d))
        pts.flat[g.integers(0, pts.size, draw(st.integers(1, pts.size)))] = draw(st.sampled_from([NAN, INF, -INF]))
        return pts
    if kind == "huge":
        return g.normal(size=(n, d)) * draw(st.sampled_from([1e4, 1e6, 1e150, 1e300]))
    if kind == "tiny":
        return g.normal(size=(n, d)) * draw(st.sampled_from([1e-6, 1e-150, 1e-300]))
    if kind == "empty":
        return np.zeros((0, d))
    return draw(st.sampled_from([np.zeros((5, 4)), np.zeros(5), "abc", [[1, 2], [3]], None, np.zeros((3, 1)),
                                 np.zeros((5, 5 - d))]))


@settings(max_examples=150, **PROFILE)
@given(d=st.sampled_from([2, 3]), data=st.data())
def test_harmony_icp_answers_or_names_the_argument(d, data):
    """Any arguments: a registration with a finite pose and ratios in [0, 1], or an HsmapError naming the argument
    (a cloud that cannot be registered, e.g. one whose points coincide, is an error, not a success at
    inlier_ratio 1.0)."""
    from hsmap import harmony_icp
    from hsmap.registration.harmony import HarmonyConfig
    from hsmap.registration.icp import RegistrationConfig, spans_its_space

    dof = 3 if d == 2 else 6
    src, tgt = data.draw(cloud(d)), data.draw(cloud(d))
    bounds = data.draw(st.one_of(
        st.none(), st.none(),
        st.builds(lambda w: np.column_stack([-np.full(dof, w), np.full(dof, w)]), st.floats(0.01, 2.0)),
        st.sampled_from([np.zeros((dof, 2)), np.ones((dof, 3)), np.array([[1.0, -1.0]] * dof),
                         np.full((dof, 2), NAN), np.column_stack([-np.full(dof, 1e308), np.full(dof, 1e308)]),
                         "abc"])))
    guesses = data.draw(st.one_of(st.none(), st.none(), st.sampled_from(
        [np.zeros(dof), np.zeros((2, dof)), np.zeros(dof + 1), np.full(dof, NAN), np.full(dof, 1e300), "x"])))
    rng = data.draw(st.sampled_from([None, 0, 7, 0, 7, -1, 2**70, True, 1.5, "seed", np.random.default_rng(1)]))
    small = RegistrationConfig(harmony=HarmonyConfig(max_iterations=15, batch_size=8), max_points=60,
                               refine_iterations=3)
    config = data.draw(st.sampled_from([small, small, small, None, "not a config"]))
    got = outcome(lambda: harmony_icp(src, tgt, bounds=bounds, initial_guesses=guesses, config=config, rng=rng),
                  *_ARGS)
    if isinstance(got, HsmapError):
        return
    for c in (src, tgt):  # what was registered had something to register
        c = np.asarray(c, dtype=float)
        assert spans_its_space(c[np.isfinite(c).all(axis=1)])
    assert np.all(np.isfinite(got.pose)) and got.pose.shape == (dof,)
    assert got.transformation.shape == (d + 1, d + 1) and np.all(np.isfinite(got.transformation))
    assert 0.0 <= got.inlier_ratio <= 1.0 and np.isfinite(got.fitness)


# --- hostile configuration files and map YAMLs -------------------------------------------------------------------

_SCALARS = st.one_of(
    st.none(), st.booleans(), st.integers(-10, 10), st.integers(-(10 ** 30), 10 ** 30), st.floats(),
    st.sampled_from(["1e-1", "1E5", "-2e3", "0x1F", "abc", "", ".inf", "1e999", "~", "yes", "!!str"]),
    st.text(max_size=20), st.text(min_size=2000, max_size=3000))


def _keys(names):
    real = [st.sampled_from(sorted(names))] if names else []
    return st.one_of(*real, st.text(max_size=8), st.integers(-3, 3), st.floats(), st.booleans(), st.none())


@st.composite
def _aliased(draw, value):
    """``value`` nested ``levels`` times in lists that repeat one object ``width`` times: YAML writes the repeats
    as aliases (&id / *id), a few hundred bytes that expand to width**levels values."""
    if draw(st.integers(0, 3)):
        return value
    for _ in range(draw(st.integers(1, 9))):
        value = [value] * draw(st.integers(2, 9))
    return value


@st.composite
def _hostile_document(draw, names: dict):
    """A mapping of real and random keys (``names``: the real keys, each with its own real sub-keys or None) to
    values of every YAML type, nested mappings of real sub-keys, and alias-expanded lists."""
    def values(sub):
        base = st.recursive(_SCALARS, lambda c: st.one_of(st.lists(c, max_size=4),
                                                           st.dictionaries(_keys(sub or {}), c, max_size=3)),
                            max_leaves=8)
        return base if not sub else st.one_of(base, _hostile_document(sub))

    doc = {}
    for key in draw(st.lists(_keys(names), max_size=4)):
        sub = names.get(key) if isinstance(key, str) else None
        doc[key] = draw(_aliased(draw(values(sub))))
    return doc


def _field_names(cls) -> dict:
    import dataclasses
    import typing

    hints = typing.get_type_hints(cls)
    return {f.name: (_field_names(hints[f.name]) if dataclasses.is_dataclass(hints.get(f.name)) else None)
            for f in dataclasses.fields(cls)}


def _short_one_line(exc: HsmapError) -> None:
    msg = str(exc)
    assert "\n" not in msg and len(msg) <= 1000, f"{type(exc).__name__} of {len(msg)} characters: {msg[:300]}"


@settings(max_examples=100, **PROFILE)
@given(which=st.sampled_from(["slam", "segmentation"]), data=st.data())
def test_hostile_config_files_load_or_give_one_short_line(which, data):
    """Random keys (names, text, numbers, null), types, nesting, aliases and sizes: a configuration or an
    HsmapError naming the file in at most 1000 characters, never another exception."""
    from hsmap.config import load_config
    from hsmap.rooms.segmentation import SegmentationConfig
    from hsmap.slam import SlamConfig

    cls = {"slam": SlamConfig, "segmentation": SegmentationConfig}[which]
    doc = data.draw(_hostile_document(_field_names(cls)))
    path = tmpdir() / "config.yaml"
    path.write_text(yaml.safe_dump(doc, allow_unicode=True))
    got = outcome(lambda: load_config(cls, path), path)
    if isinstance(got, HsmapError):
        _short_one_line(got)


@settings(max_examples=80, **PROFILE)
@given(data=st.data())
def test_hostile_map_yamls_read_or_give_one_short_line(data):
    """As above for map_server YAMLs: the good keys replaced, nested or aliased at random, random keys added."""
    from PIL import Image

    from hsmap.maps.grid import read_map

    folder = tmpdir()
    Image.fromarray(np.full((8, 8), 255, np.uint8)).save(folder / "map.png")
    names = {k: None for k in ("image", "resolution", "origin", "negate", "occupied_thresh", "free_thresh",
                               "mode")}
    meta = {"image": "map.png", "resolution": 0.05, "origin": [0.0, 0.0, 0.0]}
    meta.update(data.draw(_hostile_document(names)))
    path = folder / "map.yaml"
    path.write_text(yaml.safe_dump(meta, allow_unicode=True))
    got = outcome(lambda: read_map(path), path)
    if isinstance(got, HsmapError):
        _short_one_line(got)
