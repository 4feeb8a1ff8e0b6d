"""The 3D lab scene (pyvistaqt): lab axes, X-ray sources, detector planes, bone meshes.

With a model set, each camera appears as its source (a sphere), its detector (a quad at the
SID) textured with the current
frame (at 1.4x the source-to-origin distance when the pixel size is unknown), and the four
frustum edges; each bone as its surface mesh (iso-surface of its CT at the
bone threshold, computed once) placed by its current pose and coloured like its layer.
"""

from __future__ import annotations

import numpy as np
from PySide6 import QtCore, QtGui, QtWidgets


class ScenePane(QtWidgets.QWidget):
    """The 3D lab scene (pyvistaqt); the interactor is created on first show."""

    AXIS_LENGTH_MM = 100.0

    def __init__(self, parent: QtWidgets.QWidget | None = None, *, create_on_show: bool = True):
        super().__init__(parent)
        self.plotter = None
        self.model = None
        self._create_on_show = create_on_show
        self._scheduled = False
        self._placeholder = QtWidgets.QLabel("3D scene")
        self._placeholder.setAlignment(QtCore.Qt.AlignmentFlag.AlignCenter)
        self._layout = QtWidgets.QVBoxLayout(self)
        self._layout.setContentsMargins(0, 0, 0, 0)
        self._layout.addWidget(self._placeholder)

    def paintEvent(self, event: QtGui.QPaintEvent) -> None:
        super().paintEvent(event)
        if self._create_on_show and self.plotter is None and not self._scheduled:
            # after the first paint: the window is on screen before VTK loads (~2 s)
            self._scheduled = True
            QtCore.QTimer.singleShot(0, self.ensure_interactor)

    def ensure_interactor(self):
        """Create the ``QtInteractor`` with the lab axes (once); returns it."""
        if self.plotter is None:
            import pyvista as pv
            from pyvistaqt import QtInteractor

            plotter = QtInteractor(self, auto_update=False)
            plotter.set_background("#1e1e1e")
            length = self.AXIS_LENGTH_MM
            for axis, colour in zip(np.eye(3), ("red", "green", "blue"), strict=True):
                arrow = pv.Arrow(start=(0, 0, 0), direction=axis, scale=length)
                plotter.add_mesh(arrow, color=colour, name=f"lab-axis-{colour}")
            plotter.add_point_labels(
                1.1 * length * np.eye(3), ["X", "Y", "Z"], font_size=14, text_color="white",
                shape=None, show_points=False, name="lab-axis-labels",
            )
            plotter.add_axes()
            plotter.view_isometric()
            plotter.camera.zoom(0.8)  # room for the axis labels
            self._layout.removeWidget(self._placeholder)
            self._placeholder.hide()
            self._layout.addWidget(plotter.interactor)
            self.plotter = plotter
            if self.model is not None:
                self._populate()
        return self.plotter

    # ------------------------------------------------------------------ model
    def set_model(self, model) -> None:
        self.model = model
        model.current_frame_changed.connect(lambda f: self._update_frames())
        model.current_frame_changed.connect(lambda f: self._update_poses())
        model.pose_changed.connect(lambda b, f: self._update_poses())
        model.layer_property_changed.connect(lambda i, name: self._update_poses())
        model.selection_changed.connect(self.manipulate)
        if self.plotter is not None:
            self._populate()

    def _populate(self) -> None:
        import pyvista as pv

        m = self.model
        p = self.plotter
        self._actors = {}
        self._textures = {}
        for k, cam in enumerate(m.rig):
            # the detector at the SID; without a pixel size, 1.4x the source-origin distance
            dist = cam.sid if cam.pixel_size is not None else 1.4 * np.linalg.norm(cam.source)
            corners = cam.detector_corners(distance=dist)
            quad = pv.Rectangle(corners[:3])
            quad.texture_map_to_plane(inplace=True, origin=corners[3], point_u=corners[2],
                                      point_v=corners[0])
            self._textures[k] = p.add_mesh(quad, name=f"detector-{k}", opacity=0.9)
            p.add_mesh(pv.Sphere(radius=15.0, center=cam.source), color="yellow",
                       name=f"source-{k}")
            lines = np.vstack([np.array([cam.source, c]) for c in corners])
            p.add_lines(lines, color="#888888", width=1, name=f"frustum-{k}")
        for i, layer in enumerate(m.layers):
            mesh = self._bone_mesh(layer)
            if mesh is not None:
                self._actors[i] = p.add_mesh(mesh, color=layer.color, name=f"bone-{i}",
                                             smooth_shading=True)
        self._update_frames()
        self._update_poses()
        QtCore.QTimer.singleShot(0, self._frame_all)
        self.manipulate(m.selected)

    # ------------------------------------------------------------------ 3D manipulator
    def manipulate(self, bone: int) -> None:
        """Attach the translate/rotate widget to a bone (arrows move, rings turn it about its
        centroid); each drag is one undoable pose edit."""
        widget = getattr(self, "_widget", None)
        if widget is not None:
            widget.remove()
            self._widget = None
        if self.plotter is None or bone < 0 or bone not in getattr(self, "_actors", {}):
            return
        layer = self.model.layers[bone]
        if layer.locked:
            return
        T = self.model.pose(bone)
        centre = T[:3, :3] @ layer.centroid + T[:3, 3]
        self._drag_id = object()
        self._widget = self.plotter.add_affine_transform_widget(
            self._actors[bone], origin=tuple(float(x) for x in centre), scale=0.05,
            interact_callback=lambda M: self.widget_moved(bone, M, final=False),
            release_callback=lambda M: self.widget_moved(bone, M, final=True),
        )

    def widget_moved(self, bone: int, matrix, *, final: bool) -> None:
        """The widget's callbacks: the actor's new matrix is the bone's new pose."""
        T = np.array(matrix, dtype=float)
        if np.allclose(T, self.model.pose(bone)):
            return
        self.model.set_pose(bone, T, merge=self._drag_id, label="3D drag")
        if final:
            self.model.end_interaction()
            QtCore.QTimer.singleShot(0, lambda: self.manipulate(self.model.selected))

    def _frame_all(self) -> None:
        """Fit the whole rig (sources, detectors, bones) in view, seen from above the walkway."""
        if self.plotter is not None:
            self.plotter.view_vector((0.3, -1.0, 0.6), viewup=(0, 0, 1))
            self.plotter.reset_camera(bounds=self._focus_bounds())
            self.plotter.render()

    def _focus_bounds(self):
        """Bounds of the bones and the detectors (the sources, a metre away, would leave the
        bones a few pixels wide); None (everything) without a model."""
        if self.model is None or self.plotter is None:
            return None
        pts = []
        for name, actor in self.plotter.actors.items():
            if name.startswith(("bone-", "detector-")) and actor.GetVisibility():
                b = actor.GetBounds()
                pts += [(b[0], b[2], b[4]), (b[1], b[3], b[5])]
        if not pts:
            return None
        lo, hi = np.min(pts, axis=0), np.max(pts, axis=0)
        return (lo[0], hi[0], lo[1], hi[1], lo[2], hi[2])

    def set_cameras_visible(self, on: bool) -> None:
        """Show or hide the sources, detectors and frustums."""
        if self.plotter is None:
            return
        for name, actor in self.plotter.actors.items():
            if name.startswith(("source-", "detector-", "frustum-")):
                actor.SetVisibility(bool(on))
        self.plotter.render()

    @staticmethod
    def _bone_mesh(layer):
        import pyvista as pv

        if layer.mesh is not None:
            v, f = layer.mesh
            faces = np.hstack([np.full((len(f), 1), 3), f]).ravel()
            return pv.PolyData(np.asarray(v, float), faces)
        vol = layer.volume
        grid = pv.ImageData(dimensions=vol.shape_ijk, spacing=tuple(vol.spacing),
                            origin=tuple(vol.origin))
        grid.point_data["hu"] = np.asarray(vol.data, np.float32).transpose(2, 1, 0).ravel("F")
        surf = grid.contour([200.0], scalars="hu")
        if surf.n_points == 0:
            return None
        surf = surf.decimate(0.7) if surf.n_cells > 50000 else surf
        if not np.allclose(vol.direction, np.eye(3)):
            T = np.eye(4)
            T[:3, :3] = vol.direction
            T[:3, 3] = vol.origin - vol.direction @ vol.origin
            surf = surf.transform(T, inplace=False)
        layer.mesh = (np.asarray(surf.points), surf.faces.reshape(-1, 4)[:, 1:])
        return surf

    def _update_poses(self) -> None:
        if self.plotter is None or not hasattr(self, "_actors"):
            return
        for i, actor in self._actors.items():
            layer = self.model.layers[i]
            actor.user_matrix = self.model.pose(i)
            actor.SetVisibility(layer.visible)
            actor.prop.color = layer.color
        self.plotter.render()

    def _update_frames(self) -> None:
        if self.plotter is None or not hasattr(self, "_textures"):
            return
        import pyvista as pv

        for k, actor in self._textures.items():
            try:
                img = self.model.frame_image(k)
            except (OSError, ValueError):  # an unreadable frame: the panes say so
                continue
            if img is None:
                continue
            img = np.asarray(img, np.float32)
            lo, hi = np.percentile(img, [0.5, 99.5])
            grey = np.clip((img - lo) / max(hi - lo, 1e-6) * 255, 0, 255).astype(np.uint8)
            actor.texture = pv.numpy_to_texture(np.ascontiguousarray(grey[::-1]))
        self.plotter.render()

    def close_interactor(self) -> None:
        widget = getattr(self, "_widget", None)
        if widget is not None:
            widget.remove()
            self._widget = None
        if self.plotter is not None:
            plotter, self.plotter = self.plotter, None
            plotter.close()
