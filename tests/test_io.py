import pytest

from hsmap.errors import DataFormatError, DatasetError
from hsmap.io import atomic_open, read_number_rows


def test_atomic_open_leaves_nothing_on_error(tmp_path):
    target = tmp_path / "out.txt"
    with pytest.raises(RuntimeError), atomic_open(target) as fh:
        fh.write("partial")
        raise RuntimeError("boom")
    assert list(tmp_path.iterdir()) == []


def test_number_rows_name_the_file_and_line(tmp_path):
    p = tmp_path / "rows.txt"
    p.write_text("# a comment\n1 2\n\n3, 4\n")
    assert read_number_rows(p, "a b", "rows").tolist() == [[1, 2], [3, 4]]
    p.write_text("1 2\n3 nan\n")
    with pytest.raises(DataFormatError, match=r"rows.txt:2: NaN"):
        read_number_rows(p, "a b", "rows")
    with pytest.raises(DatasetError, match="no such file"):
        read_number_rows(tmp_path / "none.txt", "a b", "rows")


def test_to_plain_is_what_json_and_yaml_take(tmp_path):
    import enum
    import json
    from pathlib import Path

    import numpy as np
    import yaml

    from hsmap.io import to_plain, write_json

    class Kind(enum.StrEnum):
        A = "a"

    value = {1: (np.float64(0.5), np.int64(3)), "arr": np.arange(3), "kind": Kind.A, "path": Path("/x"),
             "nested": [{"b": np.bool_(True)}]}
    plain = to_plain(value)
    assert plain == {"1": [0.5, 3], "arr": [0, 1, 2], "kind": "a", "path": "/x", "nested": [{"b": True}]}
    assert type(plain["kind"]) is str and type(plain["1"][1]) is int
    yaml.safe_dump(plain)  # no numpy or enum object left for the safe dumper to choke on
    write_json(tmp_path / "v.json", value)
    assert json.loads((tmp_path / "v.json").read_text()) == plain
    with pytest.raises(TypeError, match="cannot serialise object"):
        write_json(tmp_path / "w.json", {"x": object()})


def test_ply_points_read_back_in_open3d_and_a_failed_write_leaves_nothing(tmp_path, monkeypatch):
    """hsmap writes its PLY files itself (Open3D's writer returns True on a full disk, prints, and leaves the
    file open); Open3D reads them back as written."""
    import errno
    import os

    import numpy as np
    import open3d as o3d

    from hsmap.errors import OutputError
    from hsmap.io import write_ply_points

    pts = np.random.default_rng(0).normal(size=(257, 3))
    p = write_ply_points(tmp_path / "m.ply", pts)
    np.testing.assert_array_equal(np.asarray(o3d.io.read_point_cloud(str(p)).points), pts)
    write_ply_points(tmp_path / "empty.ply", np.zeros((0, 3)))
    assert (tmp_path / "empty.ply").read_bytes().endswith(b"element vertex 0\nproperty double x\nproperty double y"
                                                          b"\nproperty double z\nend_header\n")

    def full(fd):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(os, "fsync", full)
    with pytest.raises(OutputError, match=r"m\.ply: cannot write it \(No space left on device\)$"):
        write_ply_points(tmp_path / "m.ply", pts[:5])
    monkeypatch.undo()
    assert sorted(q.name for q in tmp_path.iterdir()) == ["empty.ply", "m.ply"]
    np.testing.assert_array_equal(np.asarray(o3d.io.read_point_cloud(str(p)).points), pts)
