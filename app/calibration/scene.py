"""The solve page's 3-D scene: the calibrated cameras and the calibration object's poses.

Each camera is drawn as its X-ray source (a sphere, named), its detector at the SID (outline and a
translucent plate; at 1.4x the source-origin distance when the pixel size is unknown), the four
edges of its beam and its central ray; the spiral's beads at every adjusted pose (coloured by
frame), the static object's beads at its pose, and the lab axes (x red, y green, z blue, 50 mm).

The scene is rendered off screen by pyvista (VTK) on the GUI thread into an image shown by
:class:`SceneView`: a drag turns it about the capture volume, the wheel zooms, a double click
goes back to the first view. Rendering it once (~0.1-0.3 s) needs no OpenGL widget in the dialog,
so the page, its screenshot and the dialog's closing behave as the other pages.
"""

from __future__ import annotations

import numpy as np
from PySide6 import QtCore, QtGui

from .views import ImageView

__all__ = ["RigScene", "SceneView", "scene_from_calibration"]

SOURCE_COLOURS = ("#ff5050", "#50c0ff", "#ffd040", "#c080ff")


class RigScene:
    """An off-screen pyvista scene of a rig and object poses (module docs).

    Parameters
    ----------
    rig : sequence of :class:`core.geometry.Camera`
    poses : (F, 4, 4) array
        ``T_lab_from_object`` of the moved object in each frame.
    centers : (n, 3) array
        The moved object's bead centres in its own frame, mm.
    static_poses, static_centers : optional
        The same for the static object (the lab frame's definition).
    size : (width, height) of the rendered image in pixels.
    """

    def __init__(self, rig, poses, centers, static_poses=None, static_centers=None, *,
                 size=(900, 640)) -> None:
        import pyvista as pv

        self.size = (int(size[0]), int(size[1]))
        p = pv.Plotter(off_screen=True, window_size=list(self.size))
        p.set_background("#1e1e1e")
        self.plotter = p
        poses = np.asarray(poses, float).reshape(-1, 4, 4)
        centers = np.asarray(centers, float).reshape(-1, 3)
        beads = (np.einsum("fij,nj->fni", poses[:, :3, :3], centers) + poses[:, None, :3, 3]).reshape(-1, 3)
        scale = 1.0
        for k, cam in enumerate(rig):
            src = np.asarray(cam.source, float)
            dist = cam.sid if cam.pixel_size is not None else 1.4 * float(np.linalg.norm(src))
            corners = np.asarray(cam.detector_corners(distance=dist), float)
            scale = max(scale, float(np.linalg.norm(src)))
            col = SOURCE_COLOURS[k % len(SOURCE_COLOURS)]
            p.add_mesh(pv.Sphere(radius=0.02 * float(np.linalg.norm(src)), center=src), color=col)
            outline = pv.lines_from_points(np.vstack([corners, corners[:1]]))
            p.add_mesh(outline, color=col, line_width=3)
            p.add_mesh(pv.Rectangle(corners[:3]), color=col, opacity=0.18)
            edges = np.vstack([np.stack([src, c]) for c in corners])
            p.add_lines(edges, color="#9a9a9a", width=1)
            centre, _ = cam.detector_plane(distance=dist)
            p.add_lines(np.stack([src, centre]), color=col, width=1)
            p.add_point_labels(src[None], [f"{cam.name} source"], font_size=14, text_color=col,
                               shape=None, show_points=False, always_visible=True)
            p.add_point_labels(corners[:1], [f"{cam.name} detector"], font_size=12, text_color=col,
                               shape=None, show_points=False, always_visible=True)
        if len(beads):
            cloud = pv.PolyData(beads)
            cloud.point_data["frame"] = np.repeat(np.arange(len(poses)), len(centers)).astype(float)
            p.add_mesh(cloud, scalars="frame", cmap="viridis", point_size=5, render_points_as_spheres=True,
                       show_scalar_bar=False)
            origins = poses[:, :3, 3]
            p.add_mesh(pv.PolyData(origins), color="white", point_size=7, render_points_as_spheres=True)
        if static_poses is not None and static_centers is not None and len(static_poses):
            sp = np.asarray(static_poses, float).reshape(-1, 4, 4)
            sc = np.asarray(static_centers, float).reshape(-1, 3)
            sb = (np.einsum("fij,nj->fni", sp[:, :3, :3], sc) + sp[:, None, :3, 3]).reshape(-1, 3)
            p.add_mesh(pv.PolyData(sb), color="#ff9a30", point_size=8, render_points_as_spheres=True)
        for axis, colour in zip(np.eye(3), ("red", "green", "blue"), strict=True):
            p.add_mesh(pv.Arrow(start=(0, 0, 0), direction=axis, scale=50.0), color=colour)
        n_static = 0 if static_poses is None else len(static_poses)
        self.legend = (f"{len(rig)} cameras: source, detector outline, beam edges and central ray; "
                       f"{len(poses)} adjusted object poses (beads coloured by frame, origins white)"
                       + (f"; static object in orange ({n_static} frame)" if n_static else "")
                       + "; lab axes x/y/z red/green/blue, 50 mm. Drag: turn · wheel: zoom · "
                       "double click: first view")
        self.azimuth, self.elevation, self.zoom = 0.0, 0.0, 1.0
        self._bounds = p.bounds

    def set_size(self, width: int, height: int) -> None:
        """Render at ``width`` x ``height`` pixels from now on."""
        size = (max(int(width), 64), max(int(height), 64))
        if size != self.size:
            self.size = size
            self.plotter.window_size = list(size)

    def reset(self) -> None:
        self.azimuth, self.elevation, self.zoom = 0.0, 0.0, 1.0

    def render(self) -> np.ndarray:
        """The scene seen from the current azimuth/elevation/zoom, ``(H, W, 3)`` uint8."""
        p = self.plotter
        p.view_vector((0.35, -1.0, 0.55), viewup=(0, 0, 1))
        p.reset_camera(bounds=self._bounds)
        cam = p.camera
        cam.Azimuth(self.azimuth)
        cam.Elevation(max(-85.0, min(85.0, self.elevation)))
        cam.OrthogonalizeViewUp()
        cam.zoom(1.1 * self.zoom)
        p.reset_camera_clipping_range()
        p.render()
        img = p.screenshot(return_img=True)
        return np.ascontiguousarray(np.asarray(img)[..., :3], dtype=np.uint8)

    def close(self) -> None:
        if self.plotter is not None:
            self.plotter.close()
            self.plotter = None


def scene_from_calibration(cal, **kwargs) -> RigScene:
    """The scene of a :class:`core.calibration.session.SessionCalibration`: its rig, the moved
    object's poses and the static object's (the bundle's last poses, one per labelled static frame:
    the ``cube`` rows of ``cal.frames`` that are ok)."""
    P = np.asarray(cal.bundle.object_poses, float).reshape(-1, 4, 4)
    n = len(P) - sum(1 for r in cal.frames if r.get("group") == "cube" and r.get("ok"))
    static = cal.static_target
    return RigScene(cal.rig, P[:n], cal.target.centers, P[n:] if len(P) > n else None,
                    None if static is None else static.centers, **kwargs)


class SceneView(ImageView):
    """An :class:`ImageView` of a :class:`RigScene`: drag turns it, the wheel zooms, a double click
    resets the view. The scene is drawn again at most every 40 ms while dragging."""

    def __init__(self, parent=None) -> None:
        super().__init__(parent)
        self.scene: RigScene | None = None
        self._drag: QtCore.QPointF | None = None
        self._timer = QtCore.QTimer(self)
        self._timer.setSingleShot(True)
        self._timer.setInterval(40)
        self._timer.timeout.connect(self.redraw)
        self.setCursor(QtCore.Qt.CursorShape.OpenHandCursor)

    def set_scene(self, scene: RigScene | None) -> None:
        old, self.scene = self.scene, scene
        if old is not None and old is not scene:
            old.close()
        self.redraw()

    def redraw(self) -> None:
        if self.scene is None:
            self.set_image(None)
            self.caption = ""
        else:
            ratio = self.devicePixelRatioF()
            self.scene.set_size(round(self.width() * ratio), round(self.height() * ratio))
            self.set_rgb(self.scene.render())
            self.caption = self.scene.legend

    def resizeEvent(self, ev) -> None:
        super().resizeEvent(ev)
        if self.scene is not None and not self._timer.isActive():
            self._timer.start()

    def mousePressEvent(self, ev: QtGui.QMouseEvent) -> None:
        if ev.button() == QtCore.Qt.MouseButton.LeftButton:
            self._drag = ev.position()
        super().mousePressEvent(ev)

    def mouseMoveEvent(self, ev: QtGui.QMouseEvent) -> None:
        if self._drag is not None and self.scene is not None:
            d = ev.position() - self._drag
            self._drag = ev.position()
            self.scene.azimuth -= 0.4 * d.x()
            self.scene.elevation += 0.4 * d.y()
            if not self._timer.isActive():
                self._timer.start()
        super().mouseMoveEvent(ev)

    def mouseReleaseEvent(self, ev: QtGui.QMouseEvent) -> None:
        self._drag = None
        super().mouseReleaseEvent(ev)

    def mouseDoubleClickEvent(self, ev: QtGui.QMouseEvent) -> None:
        if self.scene is not None:
            self.scene.reset()
            self.redraw()
        super().mouseDoubleClickEvent(ev)

    def wheelEvent(self, ev: QtGui.QWheelEvent) -> None:
        if self.scene is not None:
            self.scene.zoom *= 1.2 ** (ev.angleDelta().y() / 120.0)
            self.redraw()
        ev.accept()

    def close_scene(self) -> None:
        self._timer.stop()
        self.set_scene(None)
