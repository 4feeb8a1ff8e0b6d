"""The frames of a synthetic calibration session (:mod:`core.synthetic.session`): line integrals of
the tube-bodied spiral in one view and many poses (:class:`_ObjectRenderer`), of the face plates
(hole grid, bead lattice) with their features' ideal and distorted pixels, dark frames, and the
image chain at another tube voltage."""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np

from ..geometry.camera import Camera
from .calib_objects import CalibrationObject, face_frame
from .calibration import plate_line_integrals
from .imaging import ImagingModel


def _ray_map(cam: Camera) -> np.ndarray:
    """``M`` with ``M @ (u, v, 1)`` along the lab ray through pixel ``(u, v)`` (unnormalised)."""
    return cam.R.T @ np.linalg.inv(cam.K)


def _unit_rays(M: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``(n, 3)`` unit lab directions through pixels ``(u, v)`` (elementwise: BLAS threads for
    (n, 3) @ (3, 3) products cost more than they save on a busy machine)."""
    d = u[:, None] * M[:, 0] + v[:, None] * M[:, 1] + M[:, 2]
    return d / np.sqrt(np.einsum("ij,ij->i", d, d))[:, None]


class _ObjectRenderer:
    """Line integrals of a tube-bodied object (the spiral) in one view, many poses.

    The body (foam core and polycarbonate wall: low contrast, smooth) is sampled with exact
    chords through its two cylinders at every pixel centre, or on images of 512 pixels and more
    at the centres of 2 × 2 pixel blocks interpolated (bilinear) to full resolution; the steel
    beads are rendered exactly as :func:`~core.synthetic.analytic.bead_line_integrals` with
    fluence averaging over 4 × 4 rays per pixel does (as
    :func:`~core.synthetic.calibration.object_line_integrals` calls it), without its (n, 3) @
    (3, 3) products, which OpenBLAS threads slow 30-fold on a busy 2-core machine.
    """

    def __init__(self, cam: Camera, obj: CalibrationObject, *, supersample: int = 4) -> None:
        if obj.body is None or obj.body[0] != "tube":
            raise ValueError(f"obj: expected an object with a tube body, got {obj.name}")
        self.cam, self.obj, self.ss = cam, obj, int(supersample)
        self.M, self.src = _ray_map(cam), cam.source
        b = self.block = 2 if min(cam.image_shape) >= 512 else 1
        hb, wb = -(-cam.height // b), -(-cam.width // b)
        v, u = np.mgrid[0:hb, 0:wb].astype(np.float64) * b + (b - 1) / 2
        self.coarse = (hb, wb)
        self.dirs = _unit_rays(self.M, u.ravel(), v.ravel())

    def _chords(self, T: np.ndarray, radius: float, half: float) -> np.ndarray:
        R, t = T[:3, :3], T[:3, 3]
        o = (self.src - t) @ R
        d = np.einsum("ni,ij->nj", self.dirs, R)
        a = d[:, 0] ** 2 + d[:, 1] ** 2
        b = o[0] * d[:, 0] + o[1] * d[:, 1]
        c = o[0] ** 2 + o[1] ** 2 - radius * radius
        disc = b * b - a * c
        with np.errstate(divide="ignore", invalid="ignore"):
            sq = np.sqrt(np.maximum(disc, 0.0))
            r0 = np.where(disc > 0, (-b - sq) / a, np.inf)
            r1 = np.where(disc > 0, (-b + sq) / a, -np.inf)
            za, zb = (-half - o[2]) / d[:, 2], (half - o[2]) / d[:, 2]
        flat = np.abs(d[:, 2]) < 1e-12
        z0 = np.where(flat, np.where(abs(o[2]) <= half, -np.inf, np.inf), np.minimum(za, zb))
        z1 = np.where(flat, np.where(abs(o[2]) <= half, np.inf, -np.inf), np.maximum(za, zb))
        lo = np.maximum(np.maximum(r0, z0), 0.0)
        return np.maximum(np.minimum(r1, z1) - lo, 0.0)

    def body(self, T: np.ndarray) -> np.ndarray:
        """``(H, W)`` line integrals of the body at pose ``T``."""
        _, radius, half, mu_core, wall, mu_wall = self.obj.body
        L = (mu_wall * self._chords(T, radius, half)
             + (mu_core - mu_wall) * self._chords(T, radius - wall, half)).reshape(self.coarse)
        if self.block == 1:
            return L
        # coarse sample k sits at pixel b k + (b - 1) / 2: cv2.resize's half-pixel alignment
        h, w = self.cam.image_shape
        b = self.block
        full = cv2.resize(L, (b * self.coarse[1], b * self.coarse[0]), interpolation=cv2.INTER_LINEAR)
        return full[:h, :w]

    def beads(self, T: np.ndarray) -> np.ndarray:
        """``(H, W)`` effective line integrals of the beads (μ above the foam core) at ``T``."""
        cam, ss = self.cam, self.ss
        C = self.obj.centers_lab(T)
        r = self.obj.diameters / 2
        mu = np.full(len(C), self.obj.bead_mu - self.obj.body[3])
        cube = np.array([[a, b, c] for a in (-1, 1) for b in (-1, 1) for c in (-1, 1)], dtype=float)
        uv, z = cam.project(C[:, None, :] + r[:, None, None] * cube[None], return_depth=True)
        lo = np.maximum(np.floor(uv.min(axis=1)).astype(np.int64) - 1, 0)
        hi = np.minimum(np.ceil(uv.max(axis=1)).astype(np.int64) + 2, [cam.width, cam.height])
        keep = np.nonzero(np.all(z > 0, axis=1) & np.all(hi > lo, axis=1))[0]
        out = np.zeros(cam.image_shape)
        if len(keep) == 0:
            return out
        bw, bh = hi[keep, 0] - lo[keep, 0], hi[keep, 1] - lo[keep, 1]
        npx = bw * bh
        obj = np.repeat(np.arange(len(keep)), npx)
        local = np.arange(len(obj)) - np.repeat(np.cumsum(npx) - npx, npx)
        pu = lo[keep, 0][obj] + local % bw[obj]
        pv = lo[keep, 1][obj] + local // bw[obj]
        off = (np.arange(ss) + 0.5) / ss - 0.5
        ou, ov = (a.ravel() for a in np.meshgrid(off, off))
        su = (pu[:, None] + ou[None]).ravel()
        sv = (pv[:, None] + ov[None]).ravel()
        d = _unit_rays(self.M, su, sv)
        k = np.repeat(keep[obj], ss * ss)
        w = C[k] - self.src
        t = np.einsum("ij,ij->i", w, d)
        d2 = np.einsum("ij,ij->i", w, w) - t * t
        chord = np.where(t > 0, 2.0 * np.sqrt(np.maximum(r[k] ** 2 - d2, 0.0)), 0.0)
        val = -np.log(np.mean(np.exp(-(chord * mu[k]).reshape(-1, ss * ss)), axis=1))
        np.add.at(out, (pv, pu), val)
        return out

    def __call__(self, T: np.ndarray) -> np.ndarray:
        return np.maximum(self.body(T) + self.beads(T), 0.0).astype(np.float32)


def _at_kv(model: ImagingModel, kv: float, kv_ref: float) -> ImagingModel:
    """The chain at another tube voltage: fluence and gain scale as (kV / kV_ref)²."""
    if kv == kv_ref:
        return model
    s = (kv / kv_ref) ** 2
    if model.dark_dn + model.gain_dn * s > 2**model.bits - 1:
        raise ValueError(f"kvs: {kv:g} kV saturates the {model.bits}-bit camera (gain scales as kV²)")
    photons = None if model.photons_per_pixel is None else model.photons_per_pixel * s
    return replace(model, gain_dn=model.gain_dn * s, photons_per_pixel=photons)


def _dark(model: ImagingModel, shape, g: np.random.Generator) -> np.ndarray:
    dn = np.full(shape, float(model.dark_dn))
    if model.read_noise_dn > 0:
        dn = dn + g.normal(0.0, model.read_noise_dn, size=shape)
    return np.clip(np.rint(dn), 0, 2**model.bits - 1).astype(np.uint16)


def _plate(cam: Camera, model: ImagingModel, plate, *, gap_mm: float, offset_mm, angle_rad: float):
    """Line integrals of a face plate on ``cam``'s intensifier, its pose and its features'
    ideal / distorted pixels and lab points (features inside the image only)."""
    T = face_frame(cam, gap_mm=gap_mm, thickness_mm=plate.thickness, offset_mm=offset_mm,
                   angle_rad=angle_rad)
    L = plate_line_integrals(cam, plate, T)
    pts = plate.points @ T[:3, :3].T + T[:3, 3]
    ideal = cam.project(pts)
    inside = np.all((ideal > -0.5) & (ideal < [cam.width - 0.5, cam.height - 0.5]), axis=1)
    ideal, pts = ideal[inside], pts[inside]
    dist = ideal.copy() if model.distortion is None else model.distortion.forward(ideal)
    return L, T, ideal, dist, pts


def _uv(cam: Camera, model: ImagingModel, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    ideal = cam.project(X)
    return ideal, ideal.copy() if model.distortion is None else model.distortion.forward(ideal)
