"""The real wrist sample in the window: radius overlay at its hand-found pose, bead markers.

The sample is the session's ``wrist`` fixture (tests/conftest.py), loaded once for every test that
reads it."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from app.model import ViewerModel
from core.samples import WRIST_RADIUS_POSE
from tests.app._helpers import job_ends, main_window

pytestmark = pytest.mark.gui


@pytest.fixture
def wrist_window(qtbot, wrist):
    model = ViewerModel(wrist.rig, len(wrist.frame_paths[0]),
                        frame_source=lambda view, frame: wrist.frame(view, frame))
    model.add_bone("radius", wrist.volumes["radius"], WRIST_RADIUS_POSE)
    with main_window(qtbot, size=(1400, 800)) as win:
        with job_ends(qtbot, win.pool, "overlay"):
            win.set_model(model)
        yield win


def test_wrist_beads_are_circled_in_both_views(wrist_window, qtbot, tmp_path):
    win = wrist_window
    assert sorted(win.panes[0].overlay_keys()) == [0]  # the radius DRR over the radiograph
    with job_ends(qtbot, win.pool, "markers"):
        win.layers.bead_px.setValue(10.0)
        win.layers.markers.setChecked(True)
    # the forearm carries a dozen steel beads per view (plus a few bead-like confounders)
    for pane in win.panes:
        assert 6 <= pane.marker_count <= 60
    for folder in filter(None, (tmp_path, os.environ.get("TALUS_SCREENSHOT_DIR"))):
        path = Path(folder) / "main_window_wrist.png"
        path.parent.mkdir(parents=True, exist_ok=True)
        assert win.grab().save(str(path))
    win.layers.markers.setChecked(False)  # hidden at once, no job
    assert all(p.marker_count == 0 for p in win.panes)
