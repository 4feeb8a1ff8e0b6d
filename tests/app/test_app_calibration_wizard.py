"""The calibration wizard walked with real clicks on a small rendered session: flatfield,
distortion (another model chosen), the object frames (a wrong label fixed by clicking the bead
and choosing its id, a frame excluded), the solve, saved into a study that ``talus track`` then
uses. The window stays responsive while a step computes (a timer keeps ticking) and a step can
be cancelled. The lab frame: a cube frame that cannot be labelled fails the solve, naming the
file, and the page offers the spiral's first labelled frame instead, whose calibration shows its
warning on the solve and save pages. Set ``TALUS_SCREENSHOTS=DIR`` to keep a screenshot of every
page."""

import dataclasses
import json
import os
from pathlib import Path

import numpy as np
import pytest
from PySide6 import QtCore

from tests.app._calibration_session import N_SPIRAL, PIXELS, calibration_session

pytestmark = pytest.mark.gui

# waits end on the event itself; the timeout is only the ceiling for an event that never comes
HUNG_MS = 30 * 60_000


@pytest.fixture(scope="module")
def folders(tmp_path_factory):
    """The run's shared calibration session (read only: 384 px, seed 0, 11 spiral frames) and a
    study whose trial is the demo's at the same pixels and seed (the session's rig is its rig)."""
    from core.synthetic import make_demo_study

    study = tmp_path_factory.mktemp("wizard") / "study"
    # one trial frame, coarse volumes: talus track only has to use the saved calibration
    make_demo_study(study, n_frames=1, pixels=PIXELS, seed=0, spacing=3.0, tissue_spacing=10.0,
                    calibration_session=False, device="cpu")
    return calibration_session(tmp_path_factory), study


def _shot(w, name):
    out = os.environ.get("TALUS_SCREENSHOTS")
    if out:
        w.layout().activate()  # a label whose text just grew is laid out before the picture
        QtCore.QCoreApplication.processEvents()
        Path(out).mkdir(parents=True, exist_ok=True)
        assert w.grab().save(str(Path(out) / f"calibration_wizard_{name}.png"))


def _click(qtbot, widget, pos=None):
    if pos is None:
        qtbot.mouseClick(widget, QtCore.Qt.MouseButton.LeftButton)
    else:
        qtbot.mouseClick(widget, QtCore.Qt.MouseButton.LeftButton, pos=pos)


def _step(qtbot, w, key, click):
    """Click, then wait for the step ``key`` to answer; returns the timer ticks meanwhile."""
    ticks = []
    timer = QtCore.QTimer()
    timer.setInterval(20)
    timer.timeout.connect(lambda: ticks.append(1))
    timer.start()
    with qtbot.waitSignal(w.step_done, timeout=HUNG_MS, check_params_cb=lambda k: k == key):
        click()
    timer.stop()
    assert w.results.get(key if key != "refit" else "distortion") is not None, w.status.text()
    return len(ticks)


def _click_item(qtbot, lst, row):
    rect = lst.visualItemRect(lst.item(row))
    _click(qtbot, lst.viewport(), rect.center())


def _show_frame(qtbot, w, row):
    """Click object frame ``row`` in the list and wait until its corrected images are drawn. The page
    loads the current frame (row 0) on entry: that answer may already be in, then a click on row 0
    starts nothing, so the wait is for the images, not for a step's signal (which had hung here)."""
    _click_item(qtbot, w.frame_list, row)
    qtbot.waitUntil(lambda: w.frame_list.currentRow() == row and row in w._frames, timeout=HUNG_MS)


def test_walk_the_wizard_and_track_with_its_calibration(qtbot, folders, capsys):
    from app.calibration import CalibrationWizard
    from app.cli import main as talus

    session, study = folders
    w = CalibrationWizard(session_folder=session, study_folder=study)
    qtbot.addWidget(w)
    with qtbot.waitSignal(w.step_done, timeout=HUNG_MS, check_params_cb=lambda k: k == "inspect"):
        w.show()  # the first page says what the session holds (read in the pool)
    held = f"2 dark, 3 empty-field at 70 kV, 1 grid, 1 cube, {N_SPIRAL} spiral, 1 lattice"
    assert held in w.session_info.text()
    _shot(w, "1_session")
    # flatfield: computed in the pool while the window keeps ticking
    ticks = _step(qtbot, w, "flatfield", lambda: _click(qtbot, w.next_button))
    assert ticks >= 2 and w.page == 1
    assert "inside the field" in w.ff_views[0].caption and w.rolloff_view.pixmap() is not None
    _shot(w, "2_flatfield")
    # distortion: the model table, then another model chosen
    _step(qtbot, w, "distortion", lambda: _click(qtbot, w.next_button))
    assert w.model_table.rowCount() >= 2 and len(w.grid_view.points) > 25
    w.model_combo.setCurrentText("poly(4,4)")
    _step(qtbot, w, "refit", lambda: _click(qtbot, w.refit_button))
    assert "poly(4,4)" in w.dist_info.text() and "Veiling glare" in w.dist_info.text()
    assert w.results["distortion"]["dist"].cameras[0].grid.spec.label == "poly(4,4)"
    _shot(w, "3_distortion")
    # object frames: the first try is cancelled, going back is instant, then it runs again
    with qtbot.waitSignal(w.step_done, timeout=HUNG_MS, check_params_cb=lambda k: k == "beads"):
        _click(qtbot, w.next_button)
        _click(qtbot, w.cancel_button)
    assert "beads" not in w.results and "cancelled" in w.status.text()
    _click(qtbot, w.back_button)
    assert w.page == 2 and w._running is None and w.grid_view.points.size  # kept, nothing recomputed
    ticks = _step(qtbot, w, "beads", lambda: _click(qtbot, w.next_button))
    assert ticks >= 2
    beads = w.results["beads"]
    ok = [k for k, fr in enumerate(beads.frames) if fr.ok]
    assert len(ok) >= 9, [fr.reason for fr in beads.frames]
    # a wrong label: frame k, view 1, detection i carries bead b2 (detection j's) instead of b1
    k = ok[0]
    lab = beads.frames[k].labellings[0]
    i, j = np.flatnonzero(lab.labels >= 0)[:2]
    b1, b2 = int(lab.labels[i]), int(lab.labels[j])
    from core.calibration.session import relabel

    w.results["beads"] = relabel(beads, k, 0, int(i), b2)
    _click(qtbot, w.back_button)  # back and on again: the page is drawn from the kept results
    _click(qtbot, w.next_button)
    assert w.page == 3 and w._running is None
    _show_frame(qtbot, w, k)
    assert w.frame_list.currentRow() == k and w.object_views[0].labels[i] == str(beads_ids(w)[b2])
    _shot(w, "4_object_frames")
    # fixed by hand: click detection i, choose bead b1, Assign; then detection j, bead b2
    view = w.object_views[0]
    for det, bead in ((i, b1), (j, b2)):
        _click(qtbot, view, view.widget_pos(*view.points[det]))
        assert w.assign_button.isEnabled() and view.selected == det
        w.bead_combo.setCurrentIndex(bead)
        _click(qtbot, w.assign_button)
    fixed = w.results["beads"].frames[k].labellings[0]
    assert np.array_equal(fixed.labels, lab.labels) and fixed.manual
    # a frame excluded with a click
    other = ok[1]
    _show_frame(qtbot, w, other)
    _click(qtbot, w.exclude_box)
    assert w.results["beads"].excluded == {other} and "excluded" in w.frame_list.item(other).text()
    assert "the static cube15 frame is labelled (it defines the lab frame)" in w.object_info.text()
    _shot(w, "4_object_frames_edited")
    # solve: first with a cube frame that could not be labelled (the lab frame), then as it is
    _lab_frame_choice(qtbot, w)
    cal = w.results["solve"]["cal"]
    rows = {(r["group"], r["index"]): r for r in cal.frames}
    assert rows[("spiral", other)]["reason"] == "excluded by hand" and not rows[("spiral", other)]["ok"]
    assert rows[("spiral", k)].get("manual") and cal.bundle.rms_px < 0.3
    assert w.sd_table.rowCount() == 2 and not w.reprojection_view.pixmap().isNull()
    assert w.lab_frame == "static" and cal.report["lab_frame"]["defined_by"] == "static"
    assert not cal.report["warnings"] and w.solve_warnings.isHidden()
    # the cameras and the object's poses in the 3-D scene; a drag turns it
    qtbot.waitUntil(lambda: getattr(w.scene_view.scene, "cal", None) is cal, timeout=HUNG_MS)
    scene = w.scene_view.scene
    first = w.scene_view.grab().toImage()
    qtbot.mousePress(w.scene_view, QtCore.Qt.MouseButton.LeftButton, pos=QtCore.QPoint(100, 100))
    qtbot.mouseMove(w.scene_view, QtCore.QPoint(160, 110))
    qtbot.mouseRelease(w.scene_view, QtCore.Qt.MouseButton.LeftButton, pos=QtCore.QPoint(160, 110))
    qtbot.waitUntil(lambda: w.scene_view.grab().toImage() != first, timeout=HUNG_MS)
    assert scene.azimuth != 0.0
    qtbot.mouseDClick(w.scene_view, QtCore.Qt.MouseButton.LeftButton, pos=QtCore.QPoint(100, 100))
    assert scene.azimuth == 0.0
    _shot(w, "5_solve")
    # save into the study: every trial uses it
    _click(qtbot, w.next_button)
    assert w.save_warnings.isHidden() and "lab frame: the static cube15" in w.save_summary.text()
    w.trials_combo.setCurrentText("all")
    with qtbot.waitSignal(w.saved_calibration, timeout=HUNG_MS) as saved:
        _click(qtbot, w.save_button)
    assert saved.args[0].name == "session.v1" and saved.args[0].trials == ("walk",)
    assert "session.v1" in w.save_info.text()
    _shot(w, "6_save")
    w.close()
    doc = json.loads((study / "study.json").read_text())
    assert doc["trials"]["walk"]["calibration"] == "session.v1"
    # reopened on the saved calibration
    again = CalibrationWizard.inspect_saved(study, "session.v1")
    qtbot.addWidget(again)
    assert again.session_edit.text() == str(session.absolute()) and "session.v1" in again.session_info.text()
    assert again.lab_frame == "static" and "Warning" not in again.session_info.text()
    again.close()
    # talus track uses it
    capsys.readouterr()
    # at an eighth of the resolution: the frame is corrected with the saved pipelines and registered
    # with the saved rig (--scale 8: 3.4 s of CPU on the 2-core machine with Warp's kernels compiled,
    # 5.6 s at --scale 4, 78 s at full resolution); the test is that it runs, not its accuracy
    rc = talus(["track", str(study), "--trial", "walk", "--bones", "metatarsal2", "--frames", "0:1",
                "--scale", "8", "--device", "cpu", "--no-confidence", "--quiet"])
    out = capsys.readouterr()
    assert rc == 0, out.err
    doc = json.loads(out.out)
    assert doc["normalisation"] == "saved with calibration session.v1"
    assert doc["summary"]["status"] == "complete", doc


def _use_beads(w, beads):
    """The beads step's result replaced (as a step that found them so would give it); the solve is redone."""
    w.results["beads"] = beads
    w._invalidate("solve")


def _lab_frame_choice(qtbot, w):
    """From the object page: with a cube frame that could not be labelled the solve fails, naming
    its file, and the solve page says what to do; the spiral's first labelled frame chosen in the
    lab-frame box (the keyboard) solves with a warning shown on the solve and save pages. Then the
    cube labelled and its lab frame chosen again: the solve the walk goes on with."""
    from core.calibration.matching import FrameLabels

    good = w.results["beads"]
    (fr,) = good.static_frames
    _use_beads(w, dataclasses.replace(good, static_frames=[
        FrameLabels(fr.labellings, False, "no consistent labelling", fr.distance_px)]))
    with qtbot.waitSignal(w.step_done, timeout=HUNG_MS, check_params_cb=lambda k: k == "solve"):
        _click(qtbot, w.next_button)
    assert w.page == 4 and w.lab_frame == "static"
    assert "solve" not in w.results and "solve failed" in w.status.text()
    assert "cam1/cube/0000.tif (cube15 frame 0): the static cube15 frame was recorded" in w.status.text()
    assert "could not be labelled, so it cannot define the lab frame" in w.solve_info.text()
    assert w.lab_frame_combo.itemText(1) in w.solve_info.text() and w.solve_warnings.isHidden()
    _shot(w, "5_solve_cube_not_labelled")
    _step(qtbot, w, "solve", lambda: qtbot.keyClick(w.lab_frame_combo, QtCore.Qt.Key.Key_Down))
    cal = w.results["solve"]["cal"]
    assert w.lab_frame == "object" and cal.report["lab_frame"]["defined_by"] == "object"
    (warning,) = cal.report["warnings"]
    assert "not the static cube15's" in warning
    assert not w.solve_warnings.isHidden() and warning in w.solve_warnings.text()
    qtbot.waitUntil(lambda: getattr(w.scene_view.scene, "cal", None) is cal, timeout=HUNG_MS)
    _shot(w, "5_solve_lab_frame_object")
    _click(qtbot, w.next_button)
    assert w.page == 5 and not w.save_warnings.isHidden() and warning in w.save_warnings.text()
    assert "lab frame: the first labelled frame of the spiral33" in w.save_summary.text()
    _shot(w, "6_save_lab_frame_object")
    _click(qtbot, w.back_button)
    # the cube's frame again fails; the spiral's again is its kept solve, shown at once
    with qtbot.waitSignal(w.step_done, timeout=HUNG_MS, check_params_cb=lambda k: k == "solve"):
        qtbot.keyClick(w.lab_frame_combo, QtCore.Qt.Key.Key_Up)
    assert "solve" not in w.results and w.solve_warnings.isHidden()
    qtbot.keyClick(w.lab_frame_combo, QtCore.Qt.Key.Key_Down)
    assert w._running is None and w.results["solve"]["cal"] is cal and warning in w.solve_warnings.text()
    _use_beads(w, good)  # the cube labelled: its lab frame chosen back
    _step(qtbot, w, "solve", lambda: qtbot.keyClick(w.lab_frame_combo, QtCore.Qt.Key.Key_Up))


def test_session_folder_typed_in_is_read_and_named_when_wrong(qtbot, tmp_path):
    """Opened from the menu without a folder: Next waits for one; a typed folder that is not a
    calibration session is named on the first page (read in the pool), nothing is computed."""
    from app.calibration import CalibrationWizard

    w = CalibrationWizard()
    qtbot.addWidget(w)
    w.show()
    assert not w.next_button.isEnabled()
    qtbot.keyClicks(w.session_edit, str(tmp_path))
    assert w.next_button.isEnabled()
    with qtbot.waitSignal(w.step_done, timeout=HUNG_MS, check_params_cb=lambda k: k == "inspect"):
        qtbot.keyClick(w.session_edit, QtCore.Qt.Key.Key_Return)
    assert "Not a usable calibration session" in w.session_info.text()
    assert "session.json" in w.session_info.text() and not w.results
    w.close()


def beads_ids(w):
    return w.results["flatfield"]["setup"].target.bead_ids
