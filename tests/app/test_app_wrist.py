"""The real wrist sample in the window: radius overlay at its hand-found pose, bead markers."""

from __future__ import annotations

import os
from contextlib import contextmanager
from pathlib import Path

import pytest

from app.main_window import MainWindow
from app.model import ViewerModel
from core.samples import WRIST_RADIUS_POSE, load_wrist_sample

pytestmark = pytest.mark.gui

# The tests wait for the job's own end signal (finished, failed or cancelled), however long a
# loaded machine takes to get there (Warp compiles its kernels in the first render). This is only
# the ceiling for a job that never ends, not a time the work is expected to take.
HUNG_JOB_MS = 30 * 60_000


@contextmanager
def job_ends(qtbot, pool, key: str):
    """Run the block, then wait until the pool's newest job ``key`` ends; fail unless it finished.

    Failures and cancellations end the wait at once, with the worker's message.
    """
    ends: list[tuple[str, object]] = []

    def on_finished(k, result):
        if k == key:
            ends.append(("finished", result))

    def on_failed(k, message):
        if k == key:
            ends.append(("failed", message))

    def on_cancelled(k):
        if k == key:
            ends.append(("cancelled", None))

    slots = ((pool.finished, on_finished), (pool.failed, on_failed), (pool.cancelled, on_cancelled))
    for signal, slot in slots:
        signal.connect(slot)
    try:
        yield
        qtbot.waitUntil(lambda: bool(ends), timeout=HUNG_JOB_MS)
    finally:
        for signal, slot in slots:
            signal.disconnect(slot)
    kind, payload = ends[0]
    if kind != "finished":
        pytest.fail(f"background job {key!r} {kind} instead of finishing: {payload}")


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
