"""An in-memory calibration session rendered with :mod:`core.synthetic` (tests and studies).

It has the reading interface of :class:`core.io.calibration_session.CalibrationSession`
(``cameras``, ``bit_depth``, ``frame_size``, ``manifest``, ``frames(camera, group)``,
``read(key)``) and keeps its ground truth (rig, imaging models, object poses) beside it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from core.calibration.objects import cube_target, spiral_target
from core.geometry.transforms import make_rigid
from core.synthetic import Distortion, ImagingModel, distortion_grid_frame, flatfield_frames, foot_rig
from core.synthetic.calibration import object_frames
from core.synthetic.capture import capture_centre, capture_poses


@dataclass
class MemorySession:
    cameras: tuple
    bit_depth: int
    frame_size: tuple
    manifest: dict
    images: dict = field(default_factory=dict)  # (camera, group) -> list of arrays
    truth: dict = field(default_factory=dict)

    def frames(self, camera: str, group: str) -> list:
        n = len(self.images.get((camera, group), []))
        if (camera, group) not in self.images:
            raise KeyError(f"no group {group!r} for camera {camera!r}")
        return [f"{camera}/{group}/{i:04d}.tif" for i in range(n)]

    def read(self, key) -> np.ndarray:
        cam, group, name = str(key).split("/")
        return np.asarray(self.images[(cam, group)][int(name[:4])], np.float32)


def make_memory_session(*, pixels: int = 512, n_spiral: int = 12, n_grid: int = 2, n_dark: int = 4,
                        n_flat: int = 8, seed: int = 0, cube: bool = True) -> MemorySession:
    """A small session: foot rig at ``pixels``, distortion of each view, the cube at the capture
    centre (the lab frame is the cube's), the 33-bead spiral at ``n_spiral`` poses."""
    g = np.random.default_rng(seed)
    rig = foot_rig(seed=0, pixels=pixels)
    models = [ImagingModel.fluoroscope(c, rng=g, distortion=Distortion.random(c, g)) for c in rig]
    names = tuple(c.name for c in rig)
    imgs: dict = {}
    for cam, m in zip(rig, models, strict=True):
        imgs[(cam.name, "dark")] = [m.apply(np.full(cam.image_shape, 50.0, np.float32), rng=g)
                                    for _ in range(n_dark)]
        fl, _ = flatfield_frames(cam, m, n_flat, rng=g)
        imgs[(cam.name, "flat:70")] = list(fl)
        imgs[(cam.name, "grid")] = [distortion_grid_frame(cam, m, rng=g).image for _ in range(n_grid)]
    spiral = spiral_target(33)
    poses = capture_poses(rig, spiral, n_spiral, rng=g, margin_px=0.02 * pixels)
    for T in poses:
        fr = object_frames(rig, spiral.to_synthetic(with_body=True), T, models, rng=g)
        for v, cam in enumerate(rig):
            imgs.setdefault((cam.name, "spiral"), []).append(fr.image[v])
    T_cube = make_rigid(np.eye(3), capture_centre(rig))
    if cube:
        fr = object_frames(rig, cube_target().to_synthetic(with_body=True), T_cube, models, rng=g)
        for v, cam in enumerate(rig):
            imgs[(cam.name, "cube")] = [fr.image[v]]
    manifest = {"cameras": list(names), "bit_depth": 12, "flat_kv": [70.0], "object": "spiral33",
                "static_object": "cube15", "grid": {"pitch_mm": 15.0, "hole_diameter_mm": 3.0},
                "pixel_size_mm": rig[0].pixel_size, "T_lab_from_static_object": T_cube.tolist()}
    return MemorySession(names, 12, (pixels, pixels), manifest, imgs,
                         {"rig": rig, "imaging": models, "spiral_poses": poses, "cube_pose": T_cube})
