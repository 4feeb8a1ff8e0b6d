"""A fluoroscope pane's raw/corrected toggle and its usable-pixel mask."""

import numpy as np
import pytest
from PySide6 import QtCore

pytestmark = pytest.mark.gui


def test_raw_corrected_toggle_and_usable_mask(qtbot):
    from app.panes import FluoroPane

    pane = FluoroPane("Camera 1")
    qtbot.addWidget(pane)
    raw = np.zeros((40, 50), np.uint16)
    raw[:, 10:] = 2000  # 12-bit counts; the first 10 columns are black (collimated)
    pane.set_image(raw)
    assert not pane.corrected_button.isVisible() and pane.usable_mask() is None  # no correction, no scale
    pane.set_correction(lambda r: np.asarray(r, np.float32) / 2000.0 * 0.5, full_scale=4095.0)
    pane.show()
    assert pane.corrected_button.isVisible() and pane.showing_corrected
    assert np.allclose(pane.image[:, 10:], 0.5) and pane.raw_image is raw
    qtbot.mouseClick(pane.corrected_button, QtCore.Qt.MouseButton.LeftButton)  # raw again
    assert not pane.showing_corrected and np.array_equal(pane.image, raw)
    qtbot.mouseClick(pane.usable_button, QtCore.Qt.MouseButton.LeftButton)
    m = pane.usable_mask()
    assert m.shape == raw.shape and not m[:, :10].any() and m[:, 10:].all()  # 2000/4095 is usable
    assert "__usable__" not in pane.overlay_keys() and pane.overlay_image("__usable__") is not None
    pane.set_image(raw * 0 + 4095, keep_view=True)  # saturated at full scale
    assert not pane.usable_mask().any()
    qtbot.mouseClick(pane.corrected_button, QtCore.Qt.MouseButton.LeftButton)
    assert pane.showing_corrected and pane.image.max() == pytest.approx(4095 / 2000 * 0.5)


def _bead_frame(shape, centres, background=2000, bead=700, radius=4.0):
    """12-bit counts: a flat field with dark round beads at ``centres`` (u, v)."""
    yy, xx = np.mgrid[0:shape[0], 0:shape[1]]
    img = np.full(shape, float(background))
    for u, v in centres:
        img[np.hypot(xx - u, yy - v) <= radius] = bead
    return img.astype(np.uint16)


def test_markers_layer_finds_beads_on_the_frame_the_pane_shows(qtbot):
    """The markers layer (the Markers box of the layer list) circles the beads of the frame each
    pane shows: on the corrected frame when the pane shows corrected (the study's saved correction
    moves them, here by 12 columns, and blanks what falls outside the field), on the raw frame when
    the pane is switched to raw; switching finds them again."""
    from app.controller import Controller
    from app.layers import LayerList
    from app.model import ViewerModel
    from app.panes import FluoroPane
    from app.workers import WorkerPool
    from core.synthetic import foot_rig

    shift = 12
    raw_uv = np.array([[30.0, 30.0], [70.0, 40.0], [50.0, 80.0], [90.0, 90.0]])
    raw = _bead_frame((120, 128), raw_uv)

    def correct(r):  # the saved correction: fluence, the image moved right, the left edge outside
        out = np.roll(np.asarray(r, np.float32) / 2500.0, shift, axis=1)
        out[:, :shift] = np.nan
        return out

    model = ViewerModel(foot_rig(pixels=128, seed=1), n_frames=1, frame_source=lambda view, t: raw)
    panes = [FluoroPane("Camera 1"), FluoroPane("Camera 2")]
    pool = WorkerPool()
    layers = LayerList(model)
    for w in (*panes, layers):
        qtbot.addWidget(w)
        w.show()
    ctrl = Controller(model, panes, pool, device="cpu")
    layers.markers_changed.connect(ctrl.set_markers)
    for p in panes:
        p.set_correction(correct, full_scale=4095.0)  # as attach_study_correction does
    try:
        def found(uv):
            def check():
                for p in panes:
                    got = p.markers_uv
                    assert len(got) == len(uv)
                    d = np.linalg.norm(got[:, None] - uv[None], axis=2).min(axis=1)
                    assert d.max() < 1.0, got
            qtbot.waitUntil(check, timeout=60_000)

        layers.bead_px.setValue(8.0)
        qtbot.mouseClick(layers.markers, QtCore.Qt.MouseButton.LeftButton, pos=QtCore.QPoint(6, 6))
        assert layers.markers.isChecked() and panes[0].showing_corrected
        found(raw_uv + np.array([shift, 0.0]))  # where the beads are in the corrected frame shown
        qtbot.mouseClick(panes[0].corrected_button, QtCore.Qt.MouseButton.LeftButton)
        panes[1].set_corrected(False)
        found(raw_uv)  # raw frames: the raw positions
        panes[0].set_corrected(True)
        panes[1].set_corrected(True)
        found(raw_uv + np.array([shift, 0.0]))
    finally:
        ctrl.shutdown()
        pool.shutdown(wait=True)
