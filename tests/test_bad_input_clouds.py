"""Per-point times and point counts of clouds that are not what their format says: a time field in another unit
than its driver's, NaN times, a PLY holding more vertex data than it declares, a PCD without a z field. Each is
read right or refused in one line naming the file and field; none gives a silently wrong result."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from hsmap.datasets.clouds import read_points, read_points_timed
from hsmap.datasets.ros_messages import point_time_convention, pointcloud2_points
from hsmap.errors import DataFormatError

XYZ = [("x", "f4", 7, 0), ("y", "f4", 7, 4), ("z", "f4", 7, 8)]


def _cloud(time_field, values, stamp=1_700_000_000.5):
    """A PointCloud2-like message of len(values) points with x, y, z and the time field (name, code, datatype)."""
    name, code, datatype = time_field
    fields = [*XYZ, (name, code, datatype, 16)]
    dt = np.dtype({"names": [f[0] for f in fields], "formats": ["<" + f[1] for f in fields],
                   "offsets": [f[3] for f in fields], "itemsize": 24})
    rec = np.zeros(len(values), dtype=dt)
    rec["x"] = np.arange(1, len(values) + 1)
    rec["z"] = 0.5
    rec[name] = values
    sec = int(stamp)
    return SimpleNamespace(
        header=SimpleNamespace(stamp=SimpleNamespace(sec=sec, nanosec=int(round((stamp - sec) * 1e9)))),
        fields=[SimpleNamespace(name=f[0], offset=f[3], datatype=f[2]) for f in fields],
        is_bigendian=False, point_step=24, row_step=24 * len(values), width=len(values), height=1,
        data=np.frombuffer(rec.tobytes(), np.uint8))


SWEEP = [0.0, 0.025, 0.05, 0.0996]


@pytest.mark.parametrize("name", ["t", "offset_time"])
def test_a_nanosecond_field_written_as_float_seconds_is_read_as_seconds(name):
    """Before: ouster's ``t`` or livox's ``offset_time`` written as float32 seconds was scaled by 1e-9: every point
    within 0.1 ns of the stamp, and deskewing silently did nothing."""
    pts, t, label = pointcloud2_points(_cloud((name, "f4", 7), SWEEP))
    np.testing.assert_allclose(t, SWEEP, atol=1e-6)
    assert label == f"{name} as seconds"
    assert "read as seconds" in point_time_convention(label)


@pytest.mark.parametrize("code, datatype", [("u4", 6), ("f4", 7), ("f8", 8)])
def test_nanoseconds_stay_nanoseconds_whatever_their_type(code, datatype):
    ns = [0, 25_000_000, 50_000_000, 99_600_000]
    pts, t, label = pointcloud2_points(_cloud(("t", code, datatype), ns))
    np.testing.assert_allclose(t, SWEEP, atol=1e-6)
    assert label == "t" and point_time_convention(label).startswith("ouster-ros: uint32 ns")


def test_nan_point_times_are_named_as_nan():
    """Before: 'puts points 0.0996 s from the header stamp; expected at most 1.0 s' for NaN times."""
    with pytest.raises(DataFormatError, match=r"field 't' .* holds 1 non-finite \(NaN or infinite\) time\(s\) of 4"):
        pointcloud2_points(_cloud(("t", "f4", 7), [0.0, np.nan, 0.05, 0.0996]))
    with pytest.raises(DataFormatError, match=r"field 'time' .* holds 2 non-finite"):
        pointcloud2_points(_cloud(("time", "f4", 7), [0.0, np.nan, np.inf, 0.0996]))


def _binary_pcd(path: Path, fields: list[tuple[str, str, int]], rows: dict) -> Path:
    n = len(next(iter(rows.values())))
    head = (f"# .PCD v0.7\nVERSION 0.7\nFIELDS {' '.join(f[0] for f in fields)}\n"
            f"SIZE {' '.join(str(f[2]) for f in fields)}\nTYPE {' '.join(f[1] for f in fields)}\n"
            f"COUNT {' '.join('1' for _ in fields)}\nWIDTH {n}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\n"
            "DATA binary\n")
    codes = {("F", 4): "<f4", ("F", 8): "<f8", ("U", 4): "<u4"}
    rec = np.zeros(n, dtype=[(f[0], codes[(f[1], f[2])]) for f in fields])
    for k, v in rows.items():
        rec[k] = v
    path.write_bytes(head.encode() + rec.tobytes())
    return path


def test_a_cloud_file_with_float_seconds_in_t_is_read_as_seconds(tmp_path):
    path = _binary_pcd(tmp_path / "c.pcd", [("x", "F", 4), ("y", "F", 4), ("z", "F", 4), ("t", "F", 4)],
                       {"x": [1, 2, 3, 4], "y": 0.0, "z": 0.5, "t": SWEEP})
    pts, t, label = read_points_timed(path)
    np.testing.assert_allclose(t, SWEEP, atol=1e-6)
    assert label == "t as seconds"


@pytest.mark.parametrize("fmt", ["ascii", "binary_little_endian"])
def test_a_ply_with_more_vertex_data_than_declared_is_refused(tmp_path, fmt):
    """Before: a PLY declaring 3 vertices and holding 4 was read as 3 points, the rest silently dropped."""
    pts = np.array([[1.0, 0.0, 0.5], [2.0, 0.0, 0.5], [3.0, 0.0, 0.5], [4.0, 0.0, 0.5]], np.float32)
    head = f"ply\nformat {fmt} 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nend_header\n"
    body = ("".join(f"{x} {y} {z}\n" for x, y, z in pts).encode() if fmt == "ascii" else pts.tobytes())
    path = tmp_path / "more.ply"
    path.write_bytes(head.encode() + body)
    with pytest.raises(DataFormatError, match=r"more\.ply: damaged: its header declares 3 vertices .* \(more data "
                                              r"than declared"):
        read_points(path)
    exact = tmp_path / "exact.ply"
    exact.write_bytes(head.encode() + (body[: body.index(b"4.0")] if fmt == "ascii" else pts[:3].tobytes()))
    assert len(read_points(exact)) == 3


def test_a_ply_with_faces_after_its_vertices_is_read():
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "mesh.ply"
        path.write_text("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
                        "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
                        "1 0 0.5\n0 1 0.5\n1 1 0.5\n3 0 1 2\n")
        assert len(read_points(path)) == 3


def test_a_pcd_without_a_z_field_says_so(tmp_path):
    """Before: 'its header declares 3 points, 0 could be read (the file is cut short ...)'."""
    path = tmp_path / "flat.pcd"
    path.write_text("# .PCD v0.7\nVERSION 0.7\nFIELDS x y\nSIZE 4 4\nTYPE F F\nCOUNT 1 1\nWIDTH 3\nHEIGHT 1\n"
                    "VIEWPOINT 0 0 0 1 0 0 0\nPOINTS 3\nDATA ascii\n1 0\n2 0\n3 0\n")
    with pytest.raises(DataFormatError, match=r"flat\.pcd: its PCD FIELDS are x y: no z field"):
        read_points(path)
