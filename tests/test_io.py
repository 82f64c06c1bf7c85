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
