"""The Python API as a user meets it: names where docs/ARCHITECTURE.md and the README put them, results whose parts
read alike, and signatures that show every keyword the docstrings document."""

from __future__ import annotations

import inspect
import re

import pytest
from _worlds import two_rooms

import hsmap
import hsmap.datasets
from hsmap.rooms.segmentation import segment_rooms
from hsmap.slam.run import run_slam


def test_open_dataset_is_in_hsmap_datasets():
    from hsmap.datasets.open import open_dataset

    assert hsmap.datasets.open_dataset is open_dataset
    assert "open_dataset" in hsmap.datasets.__all__


def test_a_segmentations_rooms_and_doors_are_lists():
    seg = segment_rooms(two_rooms())
    assert isinstance(seg.rooms, list) and isinstance(seg.doors, list)
    assert len(seg.rooms) == seg.n_rooms == 3
    assert [r.label for r in seg.rooms] == [1, 2, 3]
    assert all(r.area > 0 for r in seg.rooms)


def test_calling_rooms_as_the_old_method_still_works_and_warns():
    seg = segment_rooms(two_rooms())
    with pytest.warns(DeprecationWarning, match="seg.rooms"):
        rooms = seg.rooms()
    assert [r.label for r in rooms] == [r.label for r in seg.rooms]


@pytest.mark.parametrize("fn", [hsmap.harmony_icp, run_slam], ids=["harmony_icp", "run_slam"])
def test_every_documented_keyword_is_in_the_signature(fn):
    documented = set(re.findall(r"^    (\w+)(?:, \w+)* :", fn.__doc__, flags=re.MULTILINE))
    documented |= {name for line in re.findall(r"^    ((?:\w+, )+\w+) :", fn.__doc__, flags=re.MULTILINE)
                   for name in line.split(", ")}
    params = inspect.signature(fn).parameters
    assert "threads" in documented
    assert documented <= set(params), f"documented but not in the signature: {sorted(documented - set(params))}"
    assert params["threads"].kind is inspect.Parameter.KEYWORD_ONLY and params["threads"].default is None
