"""Layer list: bones with visibility, colour, opacity, lock and the overlay mode (napari-style)."""

from __future__ import annotations

import numpy as np
from PySide6 import QtCore, QtGui, QtWidgets

from .model import ViewerModel
from .overlay import MODES

__all__ = ["LayerList", "detect_markers"]


def detect_markers(inputs, diameter_px: float, max_beads: int = 200):
    """The markers layer's bead detections per view (run in a worker): ``inputs`` holds, per pane,
    :meth:`~app.panes.FluoroPane.marker_input` — ``(image, mask)`` of the frame the pane shows,
    raw or corrected by the study's saved correction — or None (no detections for that view).
    The image is scaled to its 1-99.5 % range inside the mask; pixels outside it (outside the
    field, saturated, NaN) are set to the background and no bead is kept there."""
    from core.markers import detect_beads

    out = []
    for item in inputs:
        if item is None:
            out.append(None)
            continue
        img, mask = item
        f = np.asarray(img, np.float32)
        ok = np.isfinite(f) if mask is None else (np.asarray(mask, bool) & np.isfinite(f))
        if ok.sum() < 64:
            out.append(None)
            continue
        lo, hi = np.percentile(f[ok], [1, 99.5])
        g = np.where(ok, (f - lo) / max(float(hi - lo), 1e-6), 1.0).astype(np.float32)
        out.append(detect_beads(g, diameter_px=diameter_px, max_beads=max_beads,
                                mask=None if mask is None else ok))
    return out


def _swatch(color) -> QtGui.QIcon:
    pix = QtGui.QPixmap(14, 14)
    pix.fill(QtGui.QColor.fromRgbF(*color))
    return QtGui.QIcon(pix)


class LayerList(QtWidgets.QWidget):
    """Shows the model's bones; edits go back to the model as intents.

    :attr:`held_reason` (set by the window's review actions) says why a bone's lock may not be
    lifted — handed to the window's batch, or tracked by its tracking job — or None: while it gives
    a reason, the *Locked* box of that bone stays ticked and disabled, the reason its tooltip (a
    fix unlocked by hand could be overwritten by a range task that has not reached that frame).
    """

    LOCK_TIP = "Lock the selected bone against edits (drags, nudges, keyframes)"

    mode_changed = QtCore.Signal(str)
    markers_changed = QtCore.Signal(bool, float)  # shown?, expected bead diameter (px)
    cameras_changed = QtCore.Signal(bool)

    def __init__(self, model: ViewerModel, parent: QtWidgets.QWidget | None = None) -> None:
        super().__init__(parent)
        self.model = model
        self.list = QtWidgets.QListWidget()
        self.list.setObjectName("layer-list")
        self.opacity = QtWidgets.QSlider(QtCore.Qt.Orientation.Horizontal)
        self.opacity.setRange(0, 100)
        self.opacity.setToolTip("Overlay opacity of the selected bone")
        self.locked = QtWidgets.QCheckBox("Locked")
        self.locked.setObjectName("layer-locked")
        self.locked.setToolTip(self.LOCK_TIP)
        self.held_reason = None  # callable(bone name) -> str | None (see the class docs)
        self.mode = QtWidgets.QComboBox()
        self.mode.addItems(MODES)
        self.mode.setToolTip("How bones are drawn over the fluoroscope images")
        form = QtWidgets.QFormLayout()
        form.addRow("Opacity", self.opacity)
        form.addRow("", self.locked)
        form.addRow("Overlay", self.mode)
        self.markers = QtWidgets.QCheckBox("Markers (beads)")
        self.markers.setToolTip("Detect radiopaque beads in the current frames and circle them")
        self.bead_px = QtWidgets.QDoubleSpinBox()
        self.bead_px.setRange(2.0, 60.0)
        self.bead_px.setValue(8.0)
        self.bead_px.setSuffix(" px")
        self.bead_px.setToolTip("Expected bead diameter in the images")
        self.cameras = QtWidgets.QCheckBox("Cameras (3D)")
        self.cameras.setChecked(True)
        form.addRow(self.markers, self.bead_px)
        form.addRow("", self.cameras)
        self.markers.toggled.connect(lambda on: self.markers_changed.emit(on, self.bead_px.value()))
        self.bead_px.valueChanged.connect(
            lambda v: self.markers.isChecked() and self.markers_changed.emit(True, v))
        self.cameras.toggled.connect(self.cameras_changed)
        layout = QtWidgets.QVBoxLayout(self)
        layout.setContentsMargins(4, 4, 4, 4)
        layout.addWidget(QtWidgets.QLabel("Bones"))
        layout.addWidget(self.list, 1)
        layout.addLayout(form)
        self._syncing = False
        self.list.currentRowChanged.connect(self._on_row)
        self.list.itemChanged.connect(self._on_item)
        self.opacity.valueChanged.connect(self._on_opacity)
        self.locked.toggled.connect(self._on_locked)
        self.mode.currentTextChanged.connect(self.mode_changed)
        model.layers_changed.connect(self.refresh)
        model.selection_changed.connect(self._on_selection)
        model.layer_property_changed.connect(lambda i, name: self.refresh())
        self.refresh()

    def refresh(self) -> None:
        self._syncing = True
        try:
            self.list.clear()
            for layer in self.model.layers:
                item = QtWidgets.QListWidgetItem(_swatch(layer.color), layer.name)
                item.setFlags(item.flags() | QtCore.Qt.ItemFlag.ItemIsUserCheckable)
                item.setCheckState(QtCore.Qt.CheckState.Checked if layer.visible
                                   else QtCore.Qt.CheckState.Unchecked)
                if layer.locked:
                    item.setToolTip(self._held(layer.name) or "locked")
                self.list.addItem(item)
            self.list.setCurrentRow(self.model.selected)
            self._show_selected()
        finally:
            self._syncing = False

    def _held(self, bone: str) -> str | None:
        return None if self.held_reason is None else self.held_reason(bone)

    def _show_selected(self) -> None:
        i = self.model.selected
        enabled = i >= 0
        held = self._held(self.model.layers[i].name) if enabled else None
        self.opacity.setEnabled(enabled)
        self.locked.setEnabled(enabled and held is None)
        self.locked.setToolTip(held or self.LOCK_TIP)
        if enabled:
            self.opacity.setValue(round(100 * self.model.layers[i].opacity))
            self.locked.setChecked(self.model.layers[i].locked or held is not None)

    def refresh_locks(self) -> None:
        """Show again whether the selected bone's lock may be lifted (a batch started or ended)."""
        self._syncing = True
        try:
            self._show_selected()
        finally:
            self._syncing = False

    def _on_selection(self, i: int) -> None:
        self._syncing = True
        try:
            self.list.setCurrentRow(i)
            self._show_selected()
        finally:
            self._syncing = False

    def _on_row(self, row: int) -> None:
        if not self._syncing and row >= 0:
            self.model.select(row)

    def _on_item(self, item: QtWidgets.QListWidgetItem) -> None:
        if self._syncing:
            return
        row = self.list.row(item)
        visible = item.checkState() == QtCore.Qt.CheckState.Checked
        if self.model.layers[row].visible != visible:
            self.model.set_layer_property(row, "visible", visible)

    def _on_opacity(self, value: int) -> None:
        if not self._syncing and self.model.selected >= 0:
            self.model.set_layer_property(self.model.selected, "opacity", value / 100.0)

    def _on_locked(self, checked: bool) -> None:
        if self._syncing or self.model.selected < 0:
            return
        if not checked and self._held(self.model.layers[self.model.selected].name):
            self.refresh_locks()  # refused: stays locked
            return
        self.model.set_layer_property(self.model.selected, "locked", bool(checked))
