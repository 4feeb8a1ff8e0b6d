"""Glue between the model and the widgets: frames, DRR overlays, mouse/keyboard posing.

* Frame changes show the new images in both panes and request full-resolution overlays.
* Pose edits request *preview* overlays of the edited bone at once (coarse rays, coarse steps)
  and full-resolution overlays of all bones once the interaction has paused for ``idle_ms``.
* Renders run in the :class:`~app.workers.WorkerPool` under one key, so a newer request
  supersedes an older one and only the newest overlays are ever drawn.
* A left-drag in a pane moves the selected bone in that view's plane; Ctrl+left-drag turns it
  about the ray through its centroid; the whole drag is one undo step.
"""

from __future__ import annotations

import numpy as np
from PySide6 import QtCore

from . import posing
from .layers import detect_markers
from .model import ViewerModel
from .overlay import OverlayImage, OverlayRenderer, colorize
from .panes import FluoroPane
from .workers import WorkerPool

__all__ = ["Controller"]


class Controller(QtCore.QObject):
    overlays_updated = QtCore.Signal(bool)  # preview?
    frame_failed = QtCore.Signal(str)  # a view's frame could not be read: the reason

    def __init__(self, model: ViewerModel, panes: list[FluoroPane], pool: WorkerPool, *,
                 device: str | None = None, idle_ms: int = 200,
                 parent: QtCore.QObject | None = None) -> None:
        super().__init__(parent)
        self.model = model
        self.panes = panes
        self.pool = pool
        self.mode = "blend"
        self.renderer = OverlayRenderer(model.rig, [b.volume for b in model.layers],
                                        device=device) if model.layers else None
        self._last: list[OverlayImage] = []
        self.bead_diameter_px: float | None = None  # None: markers hidden
        self._drag: dict | None = None
        self._idle = QtCore.QTimer(self)
        self._idle.setSingleShot(True)
        self._idle.setInterval(idle_ms)
        self._idle.timeout.connect(lambda: self.request_overlays(preview=False))
        model.current_frame_changed.connect(self._on_frame)
        model.pose_changed.connect(self._on_pose)
        model.layer_property_changed.connect(lambda i, name: self.recolor())
        pool.finished.connect(self._on_result)
        for view, pane in enumerate(panes):
            pane.view.pose_drag_started.connect(
                lambda kind, u, v, view=view: self._drag_start(view, kind, u, v))
            pane.view.pose_drag_moved.connect(
                lambda kind, u, v, view=view: self._drag_move(view, kind, u, v))
            pane.view.pose_drag_finished.connect(self._drag_end)
            pane.display_changed.connect(self.request_markers)  # raw/corrected: find them again
        self.show_frame(keep_view=False)
        self.request_overlays(preview=False)

    # ------------------------------------------------------------------ frames
    def show_frame(self, *, keep_view: bool = True) -> None:
        """Show the current frame in each pane; a frame whose file cannot be read leaves its pane
        saying so, and :attr:`frame_failed` tells the reason (a damaged TIFF raised out of the
        frame signal, and the pane kept the previous frame as if it were this one)."""
        for view, pane in enumerate(self.panes):
            try:
                img = self.model.frame_image(view)
            except (OSError, ValueError) as exc:
                pane.show_unreadable(f"frame {self.model.current_frame} cannot be read")
                self.frame_failed.emit(f"frame {self.model.current_frame}, view {view + 1}: {exc}")
                continue
            if img is not None:
                pane.set_image(img, keep_view=keep_view)

    def _on_frame(self, frame: int) -> None:
        self.show_frame()
        self.request_overlays(preview=False)
        self.request_markers()

    # ------------------------------------------------------------------ markers
    def set_markers(self, shown: bool, diameter_px: float) -> None:
        self.bead_diameter_px = float(diameter_px) if shown else None
        if shown:
            self.request_markers()
        else:
            for pane in self.panes:
                pane.set_markers(np.zeros((0, 2)), np.zeros(0))

    def request_markers(self) -> None:
        if self.bead_diameter_px is None or self.pool.closed:
            return
        # on the frame each pane shows (corrected by the study's saved correction, or raw)
        self.pool.submit("markers", detect_markers, [p.marker_input() for p in self.panes],
                         self.bead_diameter_px)

    # ------------------------------------------------------------------ overlays
    def request_overlays(self, *, preview: bool, bones: list[int] | None = None) -> None:
        if self.renderer is None or self.pool.closed:
            return
        bones = list(range(len(self.model.layers))) if bones is None else bones
        bones = [b for b in bones if self.model.layers[b].visible]
        if not bones:
            self.recolor()
            return
        poses = np.stack([self.model.pose(b) for b in bones])  # snapshot
        self.pool.submit("overlay", self._render, poses, tuple(bones), preview)

    def _render(self, poses, bones, preview, cancel=None):
        return preview, bones, self.renderer.render(poses, bones=bones, preview=preview,
                                                    cancel=cancel)

    def _on_result(self, key: str, result) -> None:
        if key == "markers":
            for pane, det in zip(self.panes, result, strict=False):
                if det is not None:
                    pane.set_markers(det.uv, det.radius)
            return
        if key != "overlay":
            return
        preview, bones, images = result
        if preview:  # keep the other bones' last overlays, replace the rendered ones
            keep = [o for o in self._last if o.bone not in bones]
            self._last = keep + list(images)
        else:
            self._last = list(images)
        self.recolor()
        self.overlays_updated.emit(preview)

    def set_mode(self, mode: str) -> None:
        self.mode = mode
        self.recolor()

    def recolor(self) -> None:
        """Redraw the last rendered overlays with the layers' current colour/opacity/visibility."""
        shown = set()
        for o in self._last:
            layer = self.model.layers[o.bone]
            if not layer.visible:
                continue
            rgba = colorize(o.drr, layer.color, layer.opacity, self.mode)
            self.panes[o.view].set_overlay(o.bone, rgba, o.roi, o.scale)
            shown.add((o.view, o.bone))
        for view, pane in enumerate(self.panes):
            for key in pane.overlay_keys():
                if (view, key) not in shown:
                    pane.hide_overlay(key)

    def _on_pose(self, bone: int, frame: int) -> None:
        if frame != self.model.current_frame:
            return
        self.request_overlays(preview=True, bones=[bone])
        self._idle.start()

    # ------------------------------------------------------------------ mouse posing
    def _drag_start(self, view: int, kind: str, u: float, v: float) -> None:
        i = self.model.selected
        if i < 0 or self.model.layers[i].locked:
            self._drag = None
            return
        T0 = self.model.pose(i)
        c = posing.centroid_lab(T0, self.model.layers[i].centroid)
        self._drag = {"bone": i, "view": view, "kind": kind, "T0": T0, "uv0": (u, v),
                      "centre": self.model.rig[view].project(c), "id": object()}

    def _drag_move(self, view: int, kind: str, u: float, v: float) -> None:
        d = self._drag
        if d is None or d["view"] != view:
            return
        cam = self.model.rig[view]
        layer = self.model.layers[d["bone"]]
        if d["kind"] == "rotate":
            angle = posing.drag_angle(d["centre"], d["uv0"], (u, v))
            T = posing.rotate_in_view(cam, d["T0"], layer.centroid, angle)
        else:
            T = posing.translate_in_view(cam, d["T0"], layer.centroid,
                                         u - d["uv0"][0], v - d["uv0"][1])
        self.model.set_pose(d["bone"], T, merge=d["id"], label=f"{d['kind']} in view {view + 1}")

    def _drag_end(self) -> None:
        if self._drag is not None:
            self._drag = None
            self.model.end_interaction()
            self._idle.start(0)

    def shutdown(self) -> None:
        """Stop timers (the window is closing)."""
        self._idle.stop()

    # ------------------------------------------------------------------ keyboard posing
    def nudge(self, *, translate=(0.0, 0.0, 0.0), rotate=(0.0, 0.0, 0.0)) -> None:
        i = self.model.selected
        if i < 0 or self.model.layers[i].locked:
            return
        T = posing.nudge(self.model.pose(i), self.model.layers[i].centroid,
                         translate=translate, rotate=rotate)
        self.model.set_pose(i, T, label="nudge")
