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


def test_native_stderr_is_held_back_only_when_the_output_fails(capfd):
    """What a native library prints on file descriptor 2 inside the block (Open3D's 'RPly: Error closing up' on
    a full disk) is dropped when the block ends with an OutputError (its one line says it all), and written back
    otherwise."""
    import os

    from hsmap.errors import OutputError
    from hsmap.io import native_stderr_captured

    with native_stderr_captured() as said:
        os.write(2, b"native: fine\n")
    assert said == ["native: fine\n"] and capfd.readouterr().err == "native: fine\n"
    with pytest.raises(OutputError), native_stderr_captured() as said:
        os.write(2, b"RPly: Error closing up\n")
        raise OutputError("x.ply: incomplete PLY file")
    assert said == ["RPly: Error closing up\n"] and capfd.readouterr().err == ""
    with pytest.raises(KeyboardInterrupt), native_stderr_captured():
        os.write(2, b"native: interrupted\n")
        raise KeyboardInterrupt
    assert capfd.readouterr().err == "native: interrupted\n"
