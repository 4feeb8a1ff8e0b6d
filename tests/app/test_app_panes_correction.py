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
