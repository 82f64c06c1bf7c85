import json
import subprocess
import sys

import numpy as np
import pytest
from PIL import Image

from hsmap.errors import EmptyInputError, ShapeError
from hsmap.evaluation import ground_truth_rooms, segmentation_scores
from hsmap.maps.grid import write_label_image


def _gt_two_rooms():
    """40 x 61 gray ground truth: two 40 x 30 rooms (1200 px each) split by a dark line at column 30."""
    gt = np.full((40, 61), 255, dtype=np.uint8)
    gt[:, 30] = 0
    return gt


def test_perfect_segmentation():
    gt = _gt_two_rooms()
    seg = np.zeros(gt.shape, np.int32)
    seg[:, :30] = 5
    seg[:, 31:] = 9
    s = segmentation_scores(seg, gt)
    assert (s.precision, s.recall, s.precision_area, s.recall_area) == (1.0, 1.0, 1.0, 1.0)
    assert s.n_rooms == 2 and s.n_segments == 2
    assert s.segment_precision == {5: 1.0, 9: 1.0}


def test_under_segmentation_hurts_precision():
    gt = _gt_two_rooms()
    seg = np.ones(gt.shape, np.int32)  # one segment over everything, the border line included
    s = segmentation_scores(seg, gt)
    assert s.recall == 1.0 and s.recall_area == 1.0
    assert s.precision == pytest.approx(1200 / (40 * 61))
    assert s.n_segments == 1


def test_over_segmentation_hurts_recall_by_room():
    gt = _gt_two_rooms()
    seg = np.zeros(gt.shape, np.int32)
    seg[:10, :30] = 1  # room 1 cut 10 : 30 rows
    seg[10:, :30] = 2
    seg[:, 31:] = 3
    s = segmentation_scores(seg, gt)
    assert s.precision == 1.0
    assert s.room_recall == pytest.approx([30 / 40, 1.0])
    assert s.recall == pytest.approx((0.75 + 1.0) / 2)
    assert s.recall_area == pytest.approx((900 + 1200) / 2400)


def test_mean_and_area_weighted_differ():
    # a big room (40 x 50) and a small one (12 x 12); the segmentation covers each and spills into
    # the other's border
    gt = np.full((40, 64), 255, np.uint8)
    gt[:, 50] = 0
    gt[12:, 51:] = 0  # small room: rows 0..11, cols 51..63 -> 12 x 13 = 156 px
    seg = np.zeros(gt.shape, np.int32)
    seg[:, :50] = 1
    seg[:12, 51:] = 2
    seg[12:20, 51:] = 2  # 104 extra px of segment 2 outside any room
    s = segmentation_scores(seg, gt)
    p2 = 156 / (156 + 104)
    assert s.segment_precision == pytest.approx({1: 1.0, 2: p2})
    assert s.precision == pytest.approx((1.0 + p2) / 2)
    assert s.precision_area == pytest.approx((2000 + 156) / (2000 + 260))
    assert s.recall == 1.0


def test_small_segments_and_rooms_are_ignored():
    gt = _gt_two_rooms()
    gt[0:10, 0:10] = 255
    gt[0:10, 10] = 0
    gt[10, 0:11] = 0  # a 100 px closed room in the corner: not counted (needs > 100)
    assert ground_truth_rooms(gt).max() == 2
    seg = np.zeros(gt.shape, np.int32)
    seg[:, :30] = 1
    seg[:, 31:] = 2
    seg[35:, 35:45] = 3  # 50 px segment: ignored
    seg[0:10, 31:41] = 4  # 100 px segment: ignored
    s = segmentation_scores(seg, gt)
    assert s.n_segments == 2 and s.n_rooms == 2
    assert set(s.segment_precision) == {1, 2}


def test_rooms_are_eight_connected():
    gt = np.zeros((30, 30), np.uint8)
    gt[:15, :15] = 255
    gt[15:, 15:] = 255  # touches the first block only at a corner
    assert ground_truth_rooms(gt).max() == 1
    gt[:15, :15] = 251
    assert ground_truth_rooms(gt).max() == 1  # > 250 counts
    gt[:15, :15] = 250
    assert ground_truth_rooms(gt).max() == 1 and (ground_truth_rooms(gt) > 0).sum() == 225


def test_label_ground_truth_and_errors():
    gt = _gt_two_rooms()
    labels = ground_truth_rooms(gt)
    s = segmentation_scores(labels, labels, gt_is_labels=True)
    assert s.precision == s.recall == 1.0
    with pytest.raises(ShapeError, match="differ"):
        segmentation_scores(np.zeros((5, 5), np.int32), gt)
    with pytest.raises(ShapeError, match="integers"):
        segmentation_scores(np.zeros(gt.shape), gt)
    with pytest.raises(EmptyInputError, match="no room"):
        segmentation_scores(np.zeros((20, 20), np.int32), np.zeros((20, 20), np.uint8))
    s = segmentation_scores(np.zeros(gt.shape, np.int32), gt)
    assert s.n_segments == 0 and s.precision == 0.0 and s.recall == 0.0


def _cli(*args):
    return subprocess.run([sys.executable, "-m", "hsmap.cli", *map(str, args)], capture_output=True, text=True)


def test_cli_evaluate_segmentation(tmp_path, capsys):
    gt = _gt_two_rooms()
    Image.fromarray(gt).convert("RGB").save(tmp_path / "gt.png")  # RGB like some benchmark files
    seg = np.zeros(gt.shape, np.int32)
    seg[:10, :30] = 1
    seg[10:, :30] = 300
    seg[:, 31:] = 2
    write_label_image(tmp_path / "rooms.png", seg)
    r = _cli("evaluate", "segmentation", tmp_path / "rooms.png", tmp_path / "gt.png")
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    assert out["recall"] == pytest.approx(0.875) and out["precision"] == 1.0 and out["n_segments"] == 3
    from hsmap.cli import main

    (tmp_path / "bad.png").write_text("not an image")
    assert main(["evaluate", "segmentation", str(tmp_path / "bad.png"), str(tmp_path / "gt.png")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("hsmap: error:") and "bad.png" in err
    assert main(["evaluate", "segmentation", str(tmp_path / "missing.png"), str(tmp_path / "gt.png")]) == 2
    assert "no such" in capsys.readouterr().err
    Image.fromarray(np.zeros((3, 3), np.uint8)).save(tmp_path / "small.png")
    assert main(["evaluate", "segmentation", str(tmp_path / "small.png"), str(tmp_path / "gt.png")]) == 2
    assert "differ" in capsys.readouterr().err


@pytest.mark.datasets
def test_benchmark_ground_truth_room_counts(datasets_dir):
    from hsmap.maps.grid import read_image_gray

    folder = datasets_dir / "ipa_room_segmentation"
    for name, n in (("Freiburg52_scan", 10), ("lab_c_scan", 17), ("lab_ipa", 10)):
        gt = read_image_gray(folder / f"{name}_gt_segmentation.png")
        rooms = ground_truth_rooms(gt)
        assert rooms.max() == n, name
        s = segmentation_scores(rooms, gt)
        assert s.precision == s.recall == 1.0
