"""PCD files in their three data forms (ascii, binary, PCL's LZF binary_compressed), checked against Open3D's reader
and writer, and damaged files named in one error."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from hsmap.datasets._lzf import compressed_bound, lzf_compress, lzf_decompress
from hsmap.datasets.clouds import read_points
from hsmap.datasets.pcd import read_pcd, write_pcd
from hsmap.errors import DataFormatError

o3d = pytest.importorskip("open3d")


def _records(n: int, seed: int = 0) -> np.ndarray:
    """Points as a real scanner writes them: float32 x y z, an intensity, a ring number, a 3-value field, padding."""
    rng = np.random.default_rng(seed)
    rec = np.zeros(n, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "<f4"), ("ring", "<u2"),
                             ("normal", "<f4", (3,)), ("t", "<f8")])
    rec["x"], rec["y"], rec["z"] = (rng.normal(size=(3, n)) * 5).astype("<f4")
    rec["intensity"] = rng.integers(0, 256, n)  # few values: compressible, as real intensities are
    rec["ring"] = np.arange(n) % 64
    rec["t"] = np.arange(n) * 1e-5
    return rec


def test_lzf_round_trip_of_random_and_repetitive_bytes():
    rng = np.random.default_rng(1)
    for src in (rng.integers(0, 256, 10_000).astype(np.uint8),  # incompressible: literal runs only
                np.zeros(5000, np.uint8),  # one long overlapping reference after another
                np.tile(np.arange(7, dtype=np.uint8), 2000),
                np.frombuffer(_records(3000).tobytes(), np.uint8).copy(),
                np.zeros(0, np.uint8), np.array([5], np.uint8)):
        out = np.empty(compressed_bound(src.size), np.uint8)
        n = lzf_compress(src, out)
        back = np.empty(src.size, np.uint8)
        assert lzf_decompress(out[:n], back) == src.size
        np.testing.assert_array_equal(back, src)
    assert n <= 2
    assert lzf_compress(np.zeros(5000, np.uint8), np.empty(compressed_bound(5000), np.uint8)) < 100


def test_lzf_streams_that_do_not_decode_are_refused():
    out = np.empty(100, np.uint8)
    assert lzf_decompress(np.array([5, 1, 2], np.uint8), out) == -1  # a literal run cut short
    assert lzf_decompress(np.array([0, 9, 0x20, 5], np.uint8), out) == -3  # a reference before the start
    assert lzf_decompress(np.array([31] + [1] * 32, np.uint8), np.empty(10, np.uint8)) == -2  # more than fits


@pytest.mark.parametrize("data", ["ascii", "binary", "binary_compressed"])
def test_each_data_form_round_trips_every_field(tmp_path, data):
    rec = _records(2000)
    f = tmp_path / "c.pcd"
    write_pcd(f, rec, data=data)
    assert f"DATA {data}\n".encode() in f.read_bytes()[:400]
    back = read_pcd(f)
    assert back.dtype == rec.dtype
    for name in rec.dtype.names:
        np.testing.assert_array_equal(back[name], rec[name], err_msg=name)
    # Open3D reads what was written
    np.testing.assert_allclose(np.asarray(o3d.io.read_point_cloud(str(f)).points),
                               np.column_stack([rec["x"], rec["y"], rec["z"]]), rtol=1e-6, atol=1e-6)


def test_open3d_binary_compressed_files_are_read(tmp_path):
    pts = np.random.default_rng(2).normal(size=(5000, 3)) * 4
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    pc.normals = o3d.utility.Vector3dVector(np.zeros_like(pts))
    f = tmp_path / "o3d.pcd"
    o3d.io.write_point_cloud(str(f), pc, compressed=True)
    assert b"DATA binary_compressed" in f.read_bytes()[:400]
    got = read_points(f)
    np.testing.assert_array_equal(got, pts.astype(np.float32).astype(float))
    rec = read_pcd(f)
    assert {"normal_x", "normal_y", "normal_z"} <= set(rec.dtype.names) and not np.any(rec["normal_x"])


def test_padding_fields_and_a_header_without_count_are_read(tmp_path):
    rec = np.zeros(3, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("_a", "u1", (4,))])
    rec["x"] = [1, 2, 3]
    head = ("VERSION 0.7\nFIELDS x y z _\nSIZE 4 4 4 1\nTYPE F F F U\nCOUNT 1 1 1 4\nWIDTH 3\nHEIGHT 1\n"
            "POINTS 3\nDATA binary\n")
    f = tmp_path / "pad.pcd"
    f.write_bytes(head.encode() + rec.tobytes())
    np.testing.assert_array_equal(read_points(f)[:, 0], [1, 2, 3])
    f.write_text("FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nWIDTH 2\nHEIGHT 1\nDATA ascii\n1 2 3\nnan 0 0\n")
    np.testing.assert_array_equal(read_points(f), [[1, 2, 3]])  # the NaN point is no return


def _cut(path, keep: int) -> None:
    data = path.read_bytes()
    path.write_bytes(data[:keep])


@pytest.mark.parametrize("data", ["ascii", "binary", "binary_compressed"])
def test_a_truncated_file_is_named_as_damaged(tmp_path, data):
    f = tmp_path / "cut.pcd"
    write_pcd(f, _records(1000), data=data)
    size = f.stat().st_size
    _cut(f, size - size // 3)
    with pytest.raises(DataFormatError, match=rf"^{f}: damaged: .*(cut short)"):
        read_pcd(f)
    _cut(f, f.read_bytes().index(b"DATA") + len(f"DATA {data}\n") + 3)  # only a few bytes of data
    with pytest.raises(DataFormatError, match=rf"^{f}: damaged"):
        read_points(f)


def test_a_compressed_block_that_does_not_match_its_header_is_refused(tmp_path):
    f = tmp_path / "c.pcd"
    write_pcd(f, _records(500), data="binary_compressed")
    data = bytearray(f.read_bytes())
    at = data.index(b"binary_compressed\n") + len(b"binary_compressed\n")
    packed, raw = struct.unpack("<II", data[at: at + 8])
    bad = data.copy()
    bad[at + 4: at + 8] = struct.pack("<I", raw + 8)  # the block says more bytes than 500 points hold
    f.write_bytes(bytes(bad))
    with pytest.raises(DataFormatError, match=rf"^{f}: damaged: its header declares 500 points \({raw} bytes\), its "
                                              rf"compressed block says {raw + 8} bytes"):
        read_pcd(f)
    bad = data.copy()
    bad[at + 8] = 0xFF  # the first control byte: a reference before the start
    f.write_bytes(bytes(bad))
    with pytest.raises(DataFormatError, match=rf"^{f}: damaged: its compressed block refers before its start"):
        read_pcd(f)


def test_bad_headers_are_named(tmp_path, monkeypatch):
    f = tmp_path / "h.pcd"
    f.write_text("FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nWIDTH 10\nHEIGHT 2\nPOINTS 10\nDATA binary\n")
    with pytest.raises(DataFormatError, match=r"POINTS 10, but WIDTH 10 x HEIGHT 2 = 20"):
        read_pcd(f)
    f.write_text("FIELDS x y z\nSIZE 4 4\nTYPE F F F\nWIDTH 1\nDATA binary\n")
    with pytest.raises(DataFormatError, match=r"3 FIELDS, 2 SIZE, 3 TYPE, 3 COUNT values"):
        read_pcd(f)
    f.write_text("FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nWIDTH 1\nDATA packed\n")
    with pytest.raises(DataFormatError, match=r"DATA 'packed'; expected one of ascii, binary, binary_compressed"):
        read_pcd(f)
    f.write_text("FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nWIDTH 1\n")
    with pytest.raises(DataFormatError, match=r"no DATA line"):
        read_pcd(f)
    f.write_text("FIELDS a b\nSIZE 4 4\nTYPE F F\nWIDTH 1\nDATA ascii\n1 2\n")
    with pytest.raises(DataFormatError, match=r"its PCD FIELDS are a b: no x, y, z field \(a point cloud needs x, y and z\)"):
        read_points(f)
    monkeypatch.setattr("hsmap.limits.available_memory", lambda: 8 << 30)
    f.write_text("FIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nWIDTH 500000000\nDATA binary_compressed\n")
    with pytest.raises(DataFormatError, match=rf"^{f}: 500000000 points declared in its header needs"):
        read_pcd(f)
