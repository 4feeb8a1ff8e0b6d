"""Review, fix and export in the window: live table and plots while tracking, a click on a plot
moves the frame, a flagged frame fixed, undone, fixed again and re-tracked, exports read back."""

from __future__ import annotations

import csv
import json
import shutil
import threading

import numpy as np
import pytest
from PySide6 import QtCore

from app.main_window import MainWindow
from app.review import EDITED, FLAGGED, KEYFRAME, TRACKED
from core.io.autoscoper_tra import read_tra
from core.study import Study
from core.synthetic import make_demo_study
from tests.app._helpers import FAST_TRACKING, job_ends

pytestmark = pytest.mark.gui

HUNG_JOB_MS = 30 * 60_000  # only the ceiling for a job that never ends
BONES = ["tibia", "talus", "calcaneus"]
N = 5
# the review's plumbing is tested here, not the tracker's accuracy: the GUI tests' cheap tracking
# (one pattern-search level at half resolution, no restart check, no confidence)
FAST = FAST_TRACKING


@pytest.fixture(scope="module")
def demo_folder(tmp_path_factory):
    out = tmp_path_factory.mktemp("review") / "study"
    make_demo_study(out, n_frames=N, pixels=96, seed=5, device="cpu", spacing=2.0, tissue_spacing=8.0,
                    calibration_session=False)
    return out


@pytest.fixture
def window(qtbot, demo_folder, tmp_path, monkeypatch):
    monkeypatch.setenv("TALUS_SETTINGS_DIR", str(tmp_path / "settings"))
    folder = shutil.copytree(demo_folder, tmp_path / "study")
    win = MainWindow(device="cpu", create_scene_on_show=False)
    qtbot.addWidget(win)
    win.show()
    with job_ends(qtbot, win.pool, "overlay"):
        win.open_study(folder)
    win.tracking.options = FAST
    yield win
    win.close()


def _in_front(dock) -> bool:
    """Whether a dock is shown and not behind another tab."""
    return dock.isVisible() and not dock.visibleRegion().isEmpty()


def _status(win, bone, frame):
    return int(win.review.data.status[BONES.index(bone), frame])


def test_track_review_fix_retrack_and_export(window, qtbot, demo_folder, tmp_path):
    win, m = window, window.model
    rv = win.review
    seen = []  # (tracking running?, table rows tracked, points in the plots) at each live update
    plotted = []

    def on_changed(b, f):
        table = rv.table.table_model
        n_tracked = sum(table.data(table.index(r, 2)) in ("tracked", "flagged")
                        for r in range(table.rowCount()))
        seen.append((win.tracking.running, n_tracked))

    def on_refreshed():
        y = rv.plots.curve_data("translation", 0)  # the page shown: Pose
        plotted.append((win.tracking.running, int(np.isfinite(y).sum())))

    rv.data.changed.connect(on_changed)
    rv.plots.refreshed.connect(on_refreshed)
    rv.plots_dock.raise_()  # the plots redraw while shown (a tab behind Messages catches up when shown)
    qtbot.waitUntil(rv.plots.isVisible, timeout=HUNG_JOB_MS)
    with job_ends(qtbot, win.pool, "tracking"):
        win.tracking.start(BONES)
        qtbot.waitUntil(lambda: bool(seen), timeout=HUNG_JOB_MS)  # a first result arrived
        assert win.feedback.isVisible() and "frames/s" in win.feedback.text() and "ETA" in win.feedback.text()
        # "Tracking ... over N frames" went to the messages: the plots stay in front
        assert any("Tracking" in win.messages.item(i).text() for i in range(win.messages.count()))
        assert _in_front(rv.plots_dock) and not _in_front(win.messages_dock)
    # the table and the plots filled in while the job was still running
    assert any(running and n > 0 for running, n in seen)
    assert any(running and n > 0 for running, n in plotted)
    assert seen[-1][1] == len(BONES) * N or _status(win, "talus", N - 1) in (TRACKED, FLAGGED)
    # nothing stale once it ended
    assert not win.feedback.isVisible() and not win.progress.isVisible() and not win.cancel_button.isVisible()
    assert not win.tracking.running
    assert _in_front(rv.plots_dock)  # the summary and the flagged frames did not take the front either
    win._on_failed("joint space", "Traceback ...\nValueError: no surface")  # an error does
    assert _in_front(win.messages_dock) and not _in_front(rv.plots_dock)
    rv.plots_dock.raise_()

    # a click on a plot moves to the frame under the mouse
    m.set_frame(0)
    rv.plots.show_page("Pose")
    canvas = rv.plots.canvas_of("translation")
    pos = canvas.mapFromScene(rv.plots.scene_point("translation", 3))
    qtbot.mouseClick(canvas.viewport(), QtCore.Qt.MouseButton.LeftButton, pos=pos)
    assert m.current_frame == 3
    assert rv.plots.cursor_frame == 3

    # a flagged frame: talus frame 2 registered 3 mm off and flagged by the tracker's score check
    with Study.open(win.session.folder, mode="r") as st:
        good = st.trial("walk").poses("talus")[2]
    bad = good.copy()
    bad[:3, 3] += [3.0, 0.0, 0.0]
    trial = win.session.study.trial("walk")
    why = {"flags": ["score 0.40 below 0.85 x the recent median"], "converged": False}
    trial.record_pose("talus", 2, bad, score=0.4, tracking=why)
    rv.data.reload_bone(trial, "talus")
    assert _status(win, "talus", 2) == FLAGGED
    assert win.timeline.status[2] == FLAGGED and "score 0.40" in win.timeline.tooltip(2)
    # the table's flagged filter shows it; selecting the row goes there
    rv.table.set_filter("Flagged")
    rows = rv.table.visible_rows()
    assert (BONES.index("talus"), 2) in rows and all(rv.data.status[b, f] == FLAGGED for b, f in rows)
    rv.table.select_row(rows.index((BONES.index("talus"), 2)))
    assert m.current_frame == 2 and m.layers[m.selected].name == "talus"

    # the user drags the bone to the right place (here: the true pose) and marks a keyframe
    truth = np.load(demo_folder / "poses" / "talus.npy")[2]
    m.set_layer_property("talus", "locked", False)
    m.set_pose("talus", bad)  # the window shows the flagged pose
    m.set_pose("talus", truth)
    assert win.review.keyframe_action.shortcut().toString() == "K"
    win.review.mark_keyframe()  # what K and the button do (called directly: a failure raises here)
    assert _status(win, "talus", 2) == EDITED
    # undo the fix: the tracking result comes back from the journal
    win.review.undo_fix()
    assert _status(win, "talus", 2) == FLAGGED
    np.testing.assert_allclose(m.pose("talus", 2), bad)
    # fix again and re-track forward from the frame
    m.set_pose("talus", truth)
    assert _status(win, "talus", 2) == EDITED
    with job_ends(qtbot, win.pool, "tracking"):
        win.review.retrack("forward")
    journal = trial.results("talus")
    # a new tracking result (the fast test options may flag a first frame "not converged"; the
    # reason is then the tracker's, not the old score drop)
    assert journal.records[2].kind == "tracked"
    assert "score 0.40" not in " ".join(journal.records[2].tracking["flags"])
    assert 2 in journal.keyframes  # the fix stays a keyframe
    assert _status(win, "talus", 2) in (TRACKED, FLAGGED)
    fixed = m.pose("talus", 2)
    assert not np.allclose(fixed, bad)  # registered again from the fix (accuracy at 96 px: not checked here)
    assert _status(win, "tibia", 0) in (KEYFRAME, TRACKED)

    # export: every pose format, the plots, the report; read back
    out = tmp_path / "export"
    out.mkdir()
    poses = {b: trial.poses(b) for b in trial.bones}
    win.review.export(out / "poses.tra", "tra")
    back = read_tra(out / "poses.tra", n_volumes=len(trial.bones))
    np.testing.assert_allclose(back, np.stack([poses[b] for b in trial.bones], axis=1), atol=1e-6)
    win.review.export(out / "poses.csv", "csv")
    with open(out / "poses.csv", newline="") as fh:
        rows = list(csv.reader(fh))
    assert rows[0][0] == "frame" and len(rows) == N + 1
    for b, name in enumerate(trial.bones):
        vals = np.array([[float(v) if v else np.nan for v in r[1 + 16 * b:17 + 16 * b]] for r in rows[1:]])
        np.testing.assert_allclose(vals.reshape(N, 4, 4), poses[name], atol=0, equal_nan=True)
    win.review.export(out / "poses.json", "json")
    doc = json.loads((out / "poses.json").read_text())
    np.testing.assert_allclose(np.array(doc["bones"]["talus"]["poses"][2]).reshape(4, 4), poses["talus"][2])
    for suffix in (".png", ".svg", ".pdf"):
        written = win.review.export(out / f"plots{suffix}", "plots")
        assert written[0] == out / f"plots{suffix}" and all(p.stat().st_size > 1000 for p in written)
    assert (out / "plots-Joint-angles.png").is_file()  # every page
    assert (out / "plots.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert (out / "plots.pdf").read_bytes()[:4] == b"%PDF"
    html = win.review.export(out / "report.html", "report").read_text()
    assert "Calibration" in html and "Flagged frames" in html and "ankle" in html and "data:image/png" in html
    assert win.review.export(out / "report.pdf", "report").read_bytes()[:4] == b"%PDF"


@pytest.mark.parametrize("when", ["before it starts", "while it runs"])
def test_cancel_leaves_nothing_stale(window, qtbot, when):
    """Cancel a tracking job while it waits for the (single) worker, held here by a job that waits
    on an event, or once its first frame is in: either way the job's end comes back, once, and the
    status bar keeps no feedback line, progress bar or cancel button."""
    win = window
    results = []
    win.review.data.changed.connect(lambda b, f: results.append((b, f)))
    release = threading.Event()
    if when == "before it starts":
        win.pool.submit("hold", release.wait)
    try:
        with job_ends(qtbot, win.pool, "tracking", expect="cancelled"):
            win.tracking.start(BONES)
            assert win.feedback.isVisible() and win.tracking.running
            if when == "while it runs":
                qtbot.waitUntil(lambda: bool(results), timeout=HUNG_JOB_MS)  # a first frame is in
            win.tracking.cancel()
    finally:
        release.set()
    if when == "before it starts":
        assert not results  # it never ran
    qtbot.waitUntil(lambda: not win.pool.busy, timeout=HUNG_JOB_MS)
    assert not win.tracking.running
    assert not win.feedback.isVisible() and not win.progress.isVisible() and not win.cancel_button.isVisible()
    assert not any(layer.locked for layer in win.model.layers)  # the bones are editable again


def test_window_size_suits_the_screen_and_is_remembered(qtbot, tmp_path, monkeypatch):
    monkeypatch.setenv("TALUS_SETTINGS_DIR", str(tmp_path))
    win = MainWindow(create_scene_on_show=False)
    qtbot.addWidget(win)
    avail = win.screen().availableGeometry()
    assert win.width() <= avail.width() and win.height() <= avail.height()
    assert win.width() >= min(1024, avail.width())
    win.resize(1000, 640)
    win.close()
    again = MainWindow(create_scene_on_show=False)
    qtbot.addWidget(again)
    assert (again.width(), again.height()) == (1000, 640)
    again.close()


def test_live_plot_items_repaint_only_the_frames_that_changed(qtbot):
    """The plots' curves, bands and shading ask Qt to repaint only the span of frames whose values
    changed, and a repaint of parts of the plot draws what a repaint of the whole draws."""
    from PySide6 import QtGui, QtWidgets

    from app.plots import _Live

    class Spy(_Live):
        def update(self, *rect):  # QGraphicsItem.update: what the item asks Qt to repaint
            asked.append(rect[0] if rect else None)
            super().update(*rect)

    asked = []
    n = 40
    rng = np.random.default_rng(1)
    y = rng.normal(size=(3, n))
    y[1, 10:14] = np.nan  # a gap
    scene = QtWidgets.QGraphicsScene()
    items = [Spy(n, pens=[(200, 0, 0), (0, 150, 0), (0, 0, 200)]),
             _Live(n, brushes=[(200, 0, 0, 60), (0, 150, 0, 60), (0, 0, 200, 60)]),
             _Live(n, shade=(220, 70, 60, 45))]
    for item in items:
        item.set_bounds(-4.0, 4.0)
        scene.addItem(item)
    items[0].set_data(y)
    items[1].set_data(np.stack([y - 0.3, y + 0.3], axis=1))
    items[2].set_data(np.where(rng.random(n) < 0.2, 1.0, np.nan))
    asked.clear()
    y2 = y.copy()
    y2[2, 25] += 1.0  # one frame of one curve changed
    items[0].set_data(y2)
    items[0].set_data(y2)  # the same values again: nothing to repaint
    assert len(asked) == 1 and asked[0] is not None
    assert (asked[0].left(), asked[0].right()) == (24.0, 26.0)  # the segments that reach frame 25
    assert (asked[0].top(), asked[0].bottom()) == (-4.0, 4.0)
    np.testing.assert_array_equal(items[0].series(2), y2[2])

    src = QtCore.QRectF(-1.0, -4.0, n + 1.0, 8.0)

    def render(parts: int) -> np.ndarray:
        img = QtGui.QImage(410, 120, QtGui.QImage.Format.Format_ARGB32)
        img.fill(QtGui.QColor("white"))
        painter = QtGui.QPainter(img)
        step = src.width() / parts
        for k in range(parts):  # each part repainted on its own (its exposed rectangle only)
            part = QtCore.QRectF(src.left() + k * step, src.top(), step, src.height())
            target = QtCore.QRectF(k * img.width() / parts, 0, img.width() / parts, img.height())
            scene.render(painter, target, part)
        painter.end()
        return np.frombuffer(img.constBits(), np.uint8).reshape(img.height(), img.width(), 4).copy()

    whole = render(1)
    assert (whole[..., :3] != 255).any()  # something was drawn
    np.testing.assert_array_equal(render(5), whole)
