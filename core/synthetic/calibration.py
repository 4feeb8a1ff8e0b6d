"""Ground-truth calibration frames rendered through the image chain (thesis §3.3–3.5, §5.3).

Each function renders exact line integrals (:mod:`core.synthetic.analytic`) of calibration
hardware (:mod:`core.synthetic.calib_objects`) and passes them through an
:class:`~core.synthetic.imaging.ImagingModel`, returning the 12-bit frame together with what a
calibration step should recover: ideal (pinhole) and distorted pixel positions of every feature,
their lab positions, the noise-free expected frame and the true PSF / flatfield.

Pixel positions are ``(u, v) = (column, row)``, origin at the centre of the top-left pixel.
``ideal_uv`` is the pinhole projection of a feature's centre (a hole's mid-plane centre, a
bead's centre); ``distorted_uv`` is ``distortion.forward(ideal_uv)`` (equal when the model has
no distortion). Opaque, sub-pixel-edged features are rendered with fluence averaging
(``average="fluence"``): the detector integrates photons, not line integrals.

``imaging`` may be an :class:`ImagingModel` or a :class:`Distortion`; a Distortion is wrapped in
:meth:`ImagingModel.fluoroscope` (the realistic chain, with that distortion).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..geometry.camera import Camera, Rig
from .analytic import (
    bead_line_integrals,
    box_line_integrals,
    cylinder_line_integrals,
    slab_chords,
    slab_line_integrals,
)
from .calib_objects import (
    CalibrationObject,
    FacePlate,
    bead_lattice,
    distortion_grid,
    face_frame,
    pinhole_bar,
)
from .distortion import Distortion
from .imaging import ImagingModel

__all__ = [
    "CalibrationFrame",
    "bead_lattice_frame",
    "bead_line_integrals",
    "distortion_grid_frame",
    "face_plate_frame",
    "flatfield_frames",
    "object_frames",
    "object_line_integrals",
    "pinhole_frames",
    "plate_line_integrals",
    "psf_image",
]


@dataclass(frozen=True, eq=False)
class CalibrationFrame:
    """A rendered calibration frame and its ground truth.

    Unpacks as ``image, ideal_uv, distorted_uv``. For a biplane object frame every array has a
    leading view axis.

    Attributes
    ----------
    image : (H, W) uint16, or (n_frames | n_views, H, W)
    ideal_uv, distorted_uv : (n, 2) float64 (or (n_views, n, 2))
    points_lab : (n, 3) float64
        Feature centres in the lab, mm.
    diameters : (n,) float64
        Bead or hole diameters, mm.
    expected : float64 array like ``image``
        Noise-free camera output (DN) before quantisation.
    line_integral : float32 array
        The rendered (effective) line integrals.
    psf : (k, k) float64 or None
        True point spread function (pinhole frames), normalised to sum 1 over the crop.
    """

    image: np.ndarray
    ideal_uv: np.ndarray
    distorted_uv: np.ndarray
    points_lab: np.ndarray
    diameters: np.ndarray
    expected: np.ndarray
    line_integral: np.ndarray
    psf: np.ndarray | None = None

    def __iter__(self):
        return iter((self.image, self.ideal_uv, self.distorted_uv))


def _gen(rng) -> np.random.Generator:
    return rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)


def _model(camera: Camera, imaging, g: np.random.Generator) -> ImagingModel:
    if isinstance(imaging, ImagingModel):
        return imaging
    if isinstance(imaging, Distortion):
        return ImagingModel.fluoroscope(camera, rng=g, distortion=imaging)
    raise ValueError(f"imaging: expected an ImagingModel or a Distortion, got {type(imaging).__name__}")


def _distort(model: ImagingModel, uv: np.ndarray) -> np.ndarray:
    return uv.copy() if model.distortion is None else model.distortion.forward(uv)


def _frames(model: ImagingModel, L: np.ndarray, n: int | None, g) -> np.ndarray:
    if n is None:
        return model.apply(L, rng=g)
    return np.stack([model.apply(L, rng=g) for _ in range(int(n))])


# ---------------------------------------------------------------------------- face plates
def plate_line_integrals(camera: Camera, plate: FacePlate, T_lab_from_plate, *,
                         supersample: int = 3) -> np.ndarray:
    """Effective line integrals of a face plate (uniform plate, drilled holes, embedded beads)."""
    T = np.asarray(T_lab_from_plate, dtype=float)
    n, p = T[:3, 2], T[:3, 3]
    L = slab_line_integrals(camera, p, n, plate.thickness, plate.mu).astype(np.float64)

    def base(dirs):
        return plate.mu * slab_chords(camera.source, dirs, p, n, plate.thickness)

    pts = plate.points @ T[:3, :3].T + p
    if plate.holes is not None:
        Th = np.repeat(T[None], len(pts), axis=0)
        Th[:, :3, 3] = pts
        L += cylinder_line_integrals(camera, Th, plate.hole_diameter / 2, plate.thickness / 2,
                                     -plate.mu, supersample=supersample, average="fluence",
                                     _base=base)
    if plate.beads is not None:
        L += bead_line_integrals(camera, pts, plate.bead_diameter, plate.bead_mu - plate.mu,
                                 supersample=supersample, average="fluence", _base=base)
    return np.maximum(L, 0.0).astype(np.float32)


def face_plate_frame(camera: Camera, imaging, plate: FacePlate, *, rng=0, gap_mm: float = 0.0,
                     offset_mm=(0.0, 0.0), angle_rad: float = 0.0, n_frames: int | None = None,
                     supersample: int = 3) -> CalibrationFrame:
    """Render ``plate`` lying on ``camera``'s intensifier (see :func:`calib_objects.face_frame`).

    ``n_frames=None`` returns one (H, W) frame, an int a stack of independent noisy frames.
    """
    g = _gen(rng)
    model = _model(camera, imaging, g)
    T = face_frame(camera, gap_mm=gap_mm, thickness_mm=plate.thickness, offset_mm=offset_mm,
                   angle_rad=angle_rad)
    L = plate_line_integrals(camera, plate, T, supersample=supersample)
    pts = plate.points @ T[:3, :3].T + T[:3, 3]
    ideal = camera.project(pts)
    inside = np.all((ideal > -0.5) & (ideal < [camera.width - 0.5, camera.height - 0.5]), axis=1)
    dia = plate.hole_diameter if plate.holes is not None else plate.bead_diameter
    return CalibrationFrame(
        image=_frames(model, L, n_frames, g),
        ideal_uv=ideal[inside],
        distorted_uv=_distort(model, ideal[inside]),
        points_lab=pts[inside],
        diameters=np.full(int(inside.sum()), float(dia)),
        expected=model.expected_dn(L),
        line_integral=L,
    )


def distortion_grid_frame(camera: Camera, imaging, *, rng=0, grid: FacePlate | None = None,
                          gap_mm: float = 2.0, max_offset_mm: float = 7.5, max_angle_deg: float = 2.0,
                          n_frames: int | None = None) -> CalibrationFrame:
    """A hole-grid frame (thesis §3.5.2): ~250 holes at 15 mm pitch, placed by hand (a seeded
    in-plane offset up to ``max_offset_mm`` and rotation up to ``max_angle_deg``)."""
    g = _gen(rng)
    grid = grid or distortion_grid(field_diameter_mm=camera.width * camera.pixel_size)
    off = g.uniform(-max_offset_mm, max_offset_mm, size=2)
    ang = np.radians(g.uniform(-max_angle_deg, max_angle_deg))
    return face_plate_frame(camera, imaging, grid, rng=g, gap_mm=gap_mm, offset_mm=off,
                            angle_rad=ang, n_frames=n_frames)


def bead_lattice_frame(camera: Camera, imaging, *, rng=0, lattice: FacePlate | None = None,
                       offset_mm=(0.0, 0.0), angle_rad: float = 0.0, gap_mm: float = 0.0,
                       n_frames: int | None = None) -> CalibrationFrame:
    """The bead lattice flat on the intensifier at a chosen offset/rotation (thesis §3.5.2)."""
    return face_plate_frame(camera, imaging, lattice or bead_lattice(), rng=rng, gap_mm=gap_mm,
                            offset_mm=offset_mm, angle_rad=angle_rad, n_frames=n_frames)


def psf_image(model: ImagingModel, size: int = 21) -> np.ndarray:
    """The model's point spread function (blur of a centred delta), ``(size, size)``, sum 1."""
    if int(size) != size or size < 3 or size % 2 == 0:
        raise ValueError(f"size: expected an odd integer >= 3, got {size!r}")
    big = max(int(size), int(8 * model.glare_sigma_px) | 1 if model.glare_fraction else 0) + 2 * size
    big |= 1
    delta = np.zeros((big, big))
    delta[big // 2, big // 2] = 1.0
    k = model.blur(delta)
    c, h = big // 2, size // 2
    crop = k[c - h : c + h + 1, c - h : c + h + 1]
    return crop / crop.sum()


def pinhole_frames(camera: Camera, imaging, n_frames: int = 10, *, rng=0,
                   bar: FacePlate | None = None, gap_mm: float = 0.0,
                   psf_size: int = 21) -> CalibrationFrame:
    """Frames of a lead pinhole bar on the intensifier (thesis §3.4.2) and the true PSF.

    Few quanta pass a 0.3 mm hole, so single frames are very noisy; average many (the thesis
    used 10,000).
    """
    g = _gen(rng)
    model = _model(camera, imaging, g)
    fr = face_plate_frame(camera, model, bar or pinhole_bar(), rng=g, gap_mm=gap_mm,
                          n_frames=n_frames, supersample=7)
    return CalibrationFrame(fr.image, fr.ideal_uv, fr.distorted_uv, fr.points_lab, fr.diameters,
                            fr.expected, fr.line_integral, psf_image(model, psf_size))


def flatfield_frames(camera: Camera, imaging, n_frames: int = 10, *, rng=0,
                     background: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Empty-field frames (thesis §3.3) and the true flatfield.

    ``background`` is an optional line-integral image of hardware that stays in the beam (e.g. the
    walkway plate). Returns ``(frames (n, H, W) uint16, I0 (H, W) float64 DN)``.
    """
    g = _gen(rng)
    model = _model(camera, imaging, g)
    L = np.zeros(camera.image_shape, np.float32) if background is None else np.asarray(background)
    return _frames(model, L, n_frames, g), model.expected_dn(L)


# ---------------------------------------------------------------------------- objects
def object_line_integrals(camera: Camera, obj: CalibrationObject, T_lab_from_object, *,
                          supersample: int = 4) -> np.ndarray:
    """Effective line integrals of a calibration object (body + steel beads) in one view."""
    T = np.asarray(T_lab_from_object, dtype=float)
    L = np.zeros(camera.image_shape)
    if obj.body is not None:
        kind = obj.body[0]
        if kind == "box":
            L += box_line_integrals(camera, T, obj.body[1], obj.body[2])
            body_mu = obj.body[2]
        elif kind == "tube":
            _, radius, half, mu_core, wall, mu_wall = obj.body
            L += cylinder_line_integrals(camera, np.stack([T, T]), [radius, radius - wall], half,
                                         [mu_wall, mu_core - mu_wall])
            body_mu = mu_core
        else:
            raise ValueError(f"obj.body: unknown body kind {kind!r}")
    else:
        body_mu = 0.0
    L += bead_line_integrals(camera, obj.centers_lab(T), obj.diameters, obj.bead_mu - body_mu,
                             supersample=supersample, average="fluence")
    return np.maximum(L, 0.0).astype(np.float32)


def object_frames(rig: Rig | Sequence[Camera], obj: CalibrationObject, T_lab_from_object,
                  imagings: Sequence, *, rng=0, background: Sequence[np.ndarray] | None = None,
                  supersample: int = 4) -> CalibrationFrame:
    """One biplane frame of a calibration object (cube or spiral) at ``T_lab_from_object``.

    Returns a :class:`CalibrationFrame` whose arrays have a leading view axis:
    ``image (V, H, W)``, ``ideal_uv``/``distorted_uv`` ``(V, n, 2)``; ``points_lab (n, 3)``.
    """
    cams = tuple(rig)
    if len(imagings) != len(cams):
        raise ValueError(f"imagings: expected one imaging model per camera ({len(cams)}), "
                         f"got {len(imagings)}")
    g = _gen(rng)
    pts = obj.centers_lab(T_lab_from_object)
    imgs, exp, Ls, ideal, dist = [], [], [], [], []
    for v, (cam, im) in enumerate(zip(cams, imagings, strict=True)):
        model = _model(cam, im, g)
        L = object_line_integrals(cam, obj, T_lab_from_object, supersample=supersample)
        if background is not None:
            L = L + np.asarray(background[v], dtype=np.float32)
        Ls.append(L)
        imgs.append(model.apply(L, rng=g))
        exp.append(model.expected_dn(L))
        uv = cam.project(pts)
        ideal.append(uv)
        dist.append(_distort(model, uv))
    return CalibrationFrame(np.stack(imgs), np.stack(ideal), np.stack(dist), pts, obj.diameters.copy(),
                            np.stack(exp), np.stack(Ls))
