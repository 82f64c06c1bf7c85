"""The study's recordings opened in rerun's headless viewer: every view of each quick-study recording
has content and reports no error; an empty view is caught. Skipped, saying why, where no Vulkan driver is
installed (Mesa's software renderer: ``apt-get install mesa-vulkan-drivers``; ``.ci/ensure-viewer-libs``)."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pytest

from hsmap.viz import rerun as hr
from hsmap.viz.viewer import HeadlessViewer, image_content, viewer_unavailable

REPO = Path(__file__).resolve().parents[1]
REASON = viewer_unavailable()
needs_viewer = pytest.mark.skipif(REASON is not None, reason=f"headless viewer: {REASON}")


def _png(img: np.ndarray) -> bytes:
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(img).save(buf, format="PNG")
    return buf.getvalue()


def test_image_content_measures_what_is_drawn():
    img = np.full((100, 200, 3), 13, np.uint8)
    assert image_content(_png(img)) == 0.0
    img[10:60, 20:120] = (230, 90, 30)
    assert image_content(_png(img)) == pytest.approx(50 * 100 / (100 * 200))
    img[:] = 13
    img[::10] = 20  # a faint grid (an empty 3D view): within the tolerance of the background
    assert image_content(_png(img)) == 0.0


@pytest.fixture(scope="module")
def viewer():
    with HeadlessViewer() as v:
        yield v


@needs_viewer
def test_an_empty_view_fails_the_check(tmp_path, viewer):
    """A 2D map view with nothing logged under it is an error; the 3D view with points is not."""
    path = tmp_path / "empty.rrd"
    with hr.open_recording(path, blueprint=hr.default_blueprint(graph=False)) as rec:
        hr.log_points(rec, "world/map/points", np.random.default_rng(1).uniform(0, 5, (2000, 3)), static=True,
                      radius=0.05)
    check = viewer.screenshots(path, tmp_path / "shots")
    assert not check.ok
    assert any("'2D map'" in e and "empty" in e for e in check.errors), check.errors
    assert not any("'3D world'" in e for e in check.errors), check.errors
    assert (tmp_path / "shots" / "empty-end-3d-world.png").is_file()


@pytest.mark.slow
@needs_viewer
def test_quick_study_recordings_open_with_content_in_every_view(tmp_path, viewer):
    """The quick study's four recordings through the real batch, which opens each in the viewer and fails a
    notebook whose recording has a view that errs or is empty; the SLAM run's 2D map grows along its timeline."""
    from hsmap.study.batch import run_notebooks

    result = run_notebooks(REPO / "notebooks", tmp_path / "reports", only=["01", "03", "04", "06"], quick=True,
                           log=None)
    assert [r.status for r in result.runs] == ["ok"] * 4, [(r.name, r.error) for r in result.runs]
    assert not any("viewer" in w for r in result.runs for w in r.warnings)
    recordings = sorted((tmp_path / "reports").rglob("*.rrd"))
    assert [p.name for p in recordings] == ["slam.rrd", "slam3d.rrd", "overlap.rrd", "topology.rrd"]
    # the batch opened each at the end of its timeline; the SLAM run also at its start and middle
    slam = viewer.screenshots(recordings[0], tmp_path / "shots")
    assert slam.ok, slam.errors
    assert "Legend" in slam.views
    grid = {s.position: s.content for s in slam.shots if s.view_class == "2D"}
    assert grid["end"] > 1.3 * grid["start"], grid  # the map grows with the timeline
