"""The Frames dock's Reason column: after Status, as wide as the dock leaves it, the reason elided
with the whole of it in the row's tooltip. It was the last column, past the dock's edge at the
window's default sizes (340 px at 1280x800): the reason could be read only in the tooltip."""

from __future__ import annotations

import pytest
from PySide6 import QtCore

pytestmark = pytest.mark.gui

REASON = ("frame cannot be read: view 1: /data/study/frames/cam01/frame_0003.tif: expected a "
          "single-page TIFF frame, got 0 pages")


class _Viewer:
    def select(self, bone):
        pass

    def set_frame(self, frame):
        pass


@pytest.fixture
def dock(qtbot):
    from app.review import FLAGGED, TRACKED, FrameTableDock, ReviewData

    data = ReviewData(["tibia", "talus", "calcaneus", "metatarsal2"], 6)
    data.status[:] = TRACKED
    data.score[:] = 0.5
    data.sigma_mm[:], data.sigma_deg[:] = 0.05, 0.2
    data.status[2, 3] = FLAGGED
    data.reasons[(2, 3)] = REASON
    w = FrameTableDock(data, _Viewer())
    qtbot.addWidget(w)
    w.show()
    qtbot.waitExposed(w)
    return w


def _columns(w):
    from app.review import COLUMNS

    header = w.view.horizontalHeader()
    return {name: (header.sectionViewportPosition(c), w.view.columnWidth(c))
            for c, name in enumerate(COLUMNS)}


@pytest.mark.parametrize("width", [340, 480])
def test_the_reason_is_shown_inside_the_dock(dock, qtbot, width):
    w = dock
    w.resize(width, 400)
    qtbot.wait(20)
    cols = _columns(w)
    room = w.view.viewport().width()
    x, wide = cols["Reason"]
    assert cols["Status"][0] < x  # right after Status
    assert x + wide <= room + 1 and wide >= 10 * w.view.fontMetrics().averageCharWidth()
    row = next(r for r in range(w.proxy.rowCount())
               if w.table_model.locate(w.proxy.mapToSource(w.proxy.index(r, 0)).row()) == (2, 3))
    from app.review import COLUMNS

    index = w.proxy.index(row, COLUMNS.index("Reason"))
    assert index.data(QtCore.Qt.ItemDataRole.ToolTipRole) == REASON
    assert w.view.textElideMode() == QtCore.Qt.TextElideMode.ElideRight
    if width == 480:  # room for the score beside 20 letters of reason
        assert cols["Score"][0] + cols["Score"][1] <= room + 1


def test_the_reason_fills_a_wide_dock(dock, qtbot):
    w = dock
    w.resize(900, 400)
    qtbot.wait(20)
    cols = _columns(w)
    assert sum(wide for _, wide in cols.values()) == w.view.viewport().width()  # every column shown
    assert cols["Reason"][1] > 300
