"""The Frames dock's columns at the dock's default width (340 px at 1280x800): Frame, Bone, Status
and Score in view, then the Reason, as wide as the dock leaves it, its text elided with the whole
of it in the row's tooltip and, for the row clicked, word-wrapped under the table. At 340 px the
Status shows its colour square alone and the Bone is elided, so that the Reason gets 20 letters (it
had 3), unless the user resized them (their widths kept). The Reason after Status pushed the Score
past the dock's edge at 340 px; as the last column the Reason was itself past the edge.

``TALUS_SCREENSHOTS=DIR`` keeps ``frames_reason_column.png`` (the dock at 340 and 480 px)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
from PySide6 import QtCore, QtGui

pytestmark = pytest.mark.gui

REASON = ("frame cannot be read: view 1: /data/study/frames/cam01/frame_0003.tif: expected a "
          "single-page TIFF frame, got 0 pages")
IN_VIEW = ("Frame", "Bone", "Status", "Score")


class _Viewer:
    def select(self, bone):
        pass

    def set_frame(self, frame):
        pass


def _dock(qtbot, width: int):
    from app.review import EDITED, FLAGGED, TRACKED, FrameTableDock, ReviewData

    data = ReviewData(["tibia", "talus", "calcaneus", "metatarsal2"], 6)
    data.status[:] = TRACKED
    data.score[:] = np.random.default_rng(3).uniform(0.1, 0.8, data.score.shape).round(3)
    data.sigma_mm[:], data.sigma_deg[:] = 0.05, 0.2
    for (b, f), reason in {(0, 1): "score below 0.6 x the bone's median score", (1, 2):
                           "off the trajectory (2.4 x the motion limit)", (2, 3): REASON}.items():
        data.status[b, f] = FLAGGED
        data.reasons[(b, f)] = reason
    data.status[3, 4] = EDITED
    data.reasons[(3, 4)] = "corrected by hand"
    w = FrameTableDock(data, _Viewer())
    qtbot.addWidget(w)
    w.resize(width, 400)
    w.show()
    qtbot.waitExposed(w)
    qtbot.wait(20)
    return w


def _columns(w):
    """Column name -> (left, right) in the viewport's coordinates, as the view lays them out."""
    from app.review import COLUMNS

    header = w.view.horizontalHeader()
    left = {name: header.sectionViewportPosition(c) for c, name in enumerate(COLUMNS)}
    return {name: (left[name], left[name] + w.view.columnWidth(c)) for c, name in enumerate(COLUMNS)}


def _row_of(w, bone: int, frame: int) -> int:
    return next(r for r in range(w.proxy.rowCount())
                if w.table_model.locate(w.proxy.mapToSource(w.proxy.index(r, 0)).row()) == (bone, frame))


@pytest.mark.parametrize("width", [340, 480])
def test_frame_status_and_score_in_view_then_the_reason_elided(qtbot, width):
    from app.review import COLUMNS

    w = _dock(qtbot, width)
    cols = _columns(w)
    view = w.view.viewport().rect()
    row = _row_of(w, 2, 3)
    for name in IN_VIEW:  # the cells themselves lie inside the viewport
        cell = w.view.visualRect(w.proxy.index(row, COLUMNS.index(name)))
        assert view.contains(cell), (name, cell, view)
    assert [n for n, _ in sorted(cols.items(), key=lambda kv: kv[1][0])][:5] == [*IN_VIEW, "Reason"]
    left, right = cols["Reason"]
    assert left == cols["Score"][1] and right <= view.width()  # right after Score, inside the dock
    index = w.proxy.index(row, COLUMNS.index("Reason"))
    assert index.data(QtCore.Qt.ItemDataRole.ToolTipRole) == REASON  # the whole reason
    assert w.view.textElideMode() == QtCore.Qt.TextElideMode.ElideRight
    # room for 20 letters of the reason beside the numbers; at 340 px the status's name goes (its
    # colour square stays) and the bone's name is elided to make it
    assert right - left >= 20 * w.view.fontMetrics().averageCharWidth()
    status = w.view.visualRect(w.proxy.index(row, COLUMNS.index("Status")))
    assert (status.width() < 3 * w.view.fontMetrics().height()) is (width == 340)
    assert (cols["Bone"][1] - cols["Bone"][0] >= w.view.fontMetrics().horizontalAdvance("metatarsal2")) is (
        width == 480)
    square = w.view.viewport().grab(status).toImage()
    red = sum(QtGui.QColor(square.pixel(x, y)).red() > 180 and QtGui.QColor(square.pixel(x, y)).green() < 110
              for x in range(square.width()) for y in range(square.height()))
    assert red > 20  # the flagged row's red square is drawn at either width


def test_the_row_clicked_shows_its_whole_reason_under_the_table(qtbot):
    from app.review import COLUMNS

    w = _dock(qtbot, 340)
    assert not w.reason_label.isVisible()
    row = _row_of(w, 2, 3)
    w.view.scrollTo(w.proxy.index(row, 0))
    cell = w.view.visualRect(w.proxy.index(row, COLUMNS.index("Score")))
    qtbot.mouseClick(w.view.viewport(), QtCore.Qt.MouseButton.LeftButton, pos=cell.center())
    qtbot.waitUntil(w.reason_label.isVisible)
    assert w.reason_label.text() == f"Frame 3, calcaneus: {REASON}"
    assert w.reason_label.wordWrap() and w.reason_label.width() <= 340
    # the table shrank under the label: the row clicked is scrolled back into view
    qtbot.waitUntil(lambda: w.view.viewport().rect().contains(w.view.visualRect(w.proxy.index(row, 0))))
    other = w.view.visualRect(w.proxy.index(_row_of(w, 0, 3), COLUMNS.index("Score")))  # no reason
    qtbot.mouseClick(w.view.viewport(), QtCore.Qt.MouseButton.LeftButton, pos=other.center())
    qtbot.waitUntil(lambda: not w.reason_label.isVisible())


def test_the_reason_fills_a_wide_dock(qtbot):
    w = _dock(qtbot, 900)
    cols = _columns(w)
    assert sum(r - lft for lft, r in cols.values()) == w.view.viewport().width()  # every column shown
    assert cols["Reason"][1] - cols["Reason"][0] > 300


def test_screenshot_at_340_and_480_px(qtbot):
    """Both widths side by side (kept under ``TALUS_SCREENSHOTS``); the Score's digits are drawn
    inside the 340-px dock."""
    docks = [_dock(qtbot, width) for width in (340, 480)]
    for w in docks:  # a flagged row chosen: its whole reason under the table
        w.select_row(_row_of(w, 2, 3))
        qtbot.waitUntil(w.reason_label.isVisible)
    shots = [w.grab().toImage() for w in docks]
    img = QtGui.QImage(sum(s.width() for s in shots) + 16, max(s.height() for s in shots),
                       QtGui.QImage.Format.Format_RGB32)
    img.fill(QtGui.QColor("white"))
    painter = QtGui.QPainter(img)
    painter.drawImage(0, 0, shots[0])
    painter.drawImage(shots[0].width() + 16, 0, shots[1])
    painter.end()
    narrow = _dock(qtbot, 340)
    from app.review import COLUMNS

    cell = narrow.view.visualRect(narrow.proxy.index(0, COLUMNS.index("Score")))
    pix = narrow.view.viewport().grab(cell.adjusted(2, 2, -2, -2)).toImage()
    dark = sum(QtGui.QColor(pix.pixel(x, y)).value() < 128
               for x in range(pix.width()) for y in range(pix.height()))
    assert dark > 10  # the score's text, not an empty cell
    folder = os.environ.get("TALUS_SCREENSHOTS")
    if folder:
        Path(folder).mkdir(parents=True, exist_ok=True)
        assert img.save(str(Path(folder) / "frames_reason_column.png"))


def test_the_narrow_layout_comes_and_goes_with_the_width(qtbot):
    """Widened from 340 to 480 px, the Status shows its name again at its full width and the Bone
    its whole name; a column the user widened (the header's drag sets its width) keeps its width
    when the dock is resized."""
    from app.review import COLUMNS

    w = _dock(qtbot, 340)
    status, bone, score = (COLUMNS.index(n) for n in ("Status", "Bone", "Score"))
    narrow = w.view.columnWidth(status), w.view.columnWidth(bone)
    w.resize(480, 400)
    qtbot.waitUntil(lambda: w.view.columnWidth(status) > narrow[0])
    assert not w._status_delegate.compact and w.view.columnWidth(bone) > narrow[1]
    assert w.view.columnWidth(bone) >= w.view.fontMetrics().horizontalAdvance("metatarsal2")
    wider = w.view.columnWidth(score) + 15
    w.view.setColumnWidth(score, wider)
    w.resize(700, 400)
    qtbot.waitUntil(lambda: w.view.viewport().width() > 600)
    assert w.view.columnWidth(score) == wider
    w.resize(340, 400)
    qtbot.waitUntil(lambda: w._status_delegate.compact)
    assert w.view.columnWidth(status) == narrow[0]


def test_status_and_bone_the_user_resized_keep_their_widths(qtbot):
    """The narrow layout narrows Status and Bone only where the user has not resized them (the
    header's drag sets the width): a Bone widened at 480 px stays so at 340 px and back at 480 px
    (it was elided, then put back to the font's width), a Status widened at 340 px shows its name
    at that width; the Reason gets what is left. A Bone the layout elided beside a Status the
    user set comes back to its whole width in a wide dock."""
    from app.review import COLUMNS

    w = _dock(qtbot, 480)
    status, bone = COLUMNS.index("Status"), COLUMNS.index("Bone")
    fm = w.view.fontMetrics()
    wide_bone = w.view.columnWidth(bone) + 30
    w.view.setColumnWidth(bone, wide_bone)
    for width in (340, 480):
        w.resize(width, 400)
        qtbot.waitUntil(lambda width=width: abs(w.width() - width) < 2)
        qtbot.wait(20)
        assert w.view.columnWidth(bone) == wide_bone
    w.resize(340, 400)
    qtbot.waitUntil(lambda: w._status_delegate.compact)
    wide_status = fm.horizontalAdvance("flagged") + 3 * fm.height()
    w.view.setColumnWidth(status, wide_status)  # its name shown again, at the user's width
    assert not w._status_delegate.compact and w.view.columnWidth(status) == wide_status
    w.resize(360, 400)
    qtbot.waitUntil(lambda: abs(w.width() - 360) < 2)
    qtbot.wait(20)
    assert w.view.columnWidth(status) == wide_status and w.view.columnWidth(bone) == wide_bone

    w = _dock(qtbot, 340)  # the Bone elided, then the Status set by the user: the Bone comes back
    full_bone = w._widths[bone]
    w.view.setColumnWidth(status, w._widths[status])
    assert w.view.columnWidth(bone) < full_bone
    w.resize(900, 400)
    qtbot.waitUntil(lambda: w.view.columnWidth(bone) == full_bone)
    assert w.view.columnWidth(status) == w._widths[status]
