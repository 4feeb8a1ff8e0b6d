"""The real wrist sample in the window: radius overlay at its hand-found pose, bead markers."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from app.main_window import MainWindow
from app.model import ViewerModel
from core.samples import WRIST_RADIUS_POSE, load_wrist_sample
from tests.app._helpers import job_ends

pytestmark = pytest.mark.gui


@pytest.fixture
def wrist_window(qtbot, sample_data):
    folder = sample_data / "autoscoper_wrist"
    if not folder.is_dir():
        pytest.skip(reason=f"wrist sample not found at {folder}")
    sample = load_wrist_sample(folder)
    model = ViewerModel(sample.rig, len(sample.frame_paths[0]),
                        frame_source=lambda view, frame: sample.frame(view, frame))
    model.add_bone("radius", sample.volumes["radius"], WRIST_RADIUS_POSE)
    win = MainWindow(device="cpu", create_scene_on_show=False)
    qtbot.addWidget(win)
    win.resize(1400, 800)
    win.show()
    with job_ends(qtbot, win.pool, "overlay"):
        win.set_model(model)
    yield win
    win.close()


def test_wrist_beads_are_circled_in_both_views(wrist_window, qtbot, tmp_path):
    win = wrist_window
    assert sorted(win.panes[0].overlay_keys()) == [0]  # the radius DRR over the radiograph
    with job_ends(qtbot, win.pool, "markers"):
        win.layers.bead_px.setValue(10.0)
        win.layers.markers.setChecked(True)
    # the forearm carries a dozen steel beads per view (plus a few bead-like confounders)
    for pane in win.panes:
        assert 6 <= pane.marker_count <= 60
    win.layers.markers.setChecked(False)
    assert all(p.marker_count == 0 for p in win.panes)
    with job_ends(qtbot, win.pool, "markers"):
        win.layers.markers.setChecked(True)
    assert all(p.marker_count > 0 for p in win.panes)
    for folder in filter(None, (tmp_path, os.environ.get("TALUS_SCREENSHOT_DIR"))):
        path = Path(folder) / "main_window_wrist.png"
        path.parent.mkdir(parents=True, exist_ok=True)
        assert win.grab().save(str(path))
