"""Image-intensifier spatial distortion: radial pincushion plus the S-shaped magnetic twist.

Physics (thesis §3.5.1; Gronenschild 1999; Fahrig et al. 1997)
--------------------------------------------------------------
* **Pincushion.** The intensifier's input phosphor is curved, so a flat object is imaged with a
  magnification that grows with distance from the axis: a point at normalised radius ``r`` moves
  outward to ``ρ = r (1 + k1 r² + k2 r⁴)``.
* **S-distortion.** External magnetic fields (the Earth's, ~50 µT, and nearby equipment) bend the
  photo-electrons on their way from the input to the output phosphor. The axial component twists
  the image by an angle that grows with radius (electrons from the rim travel longest off-axis),
  so a straight line through the centre becomes an "S". Modelled as a rotation about the
  distortion centre by ``φ(r) = twist · r^power``. Its sign and size depend on the intensifier's
  orientation in the field, so the two views of a rig differ.

Coordinates are pixels ``(u, v) = (column, row)``, origin at the centre of the top-left pixel;
``r = |uv - center| / scale_px``. The forward map takes *ideal* (undistorted, pinhole) pixel
positions to *distorted* (observed) ones; :meth:`Distortion.inverse` undoes it exactly (Newton on
the monotonic radial polynomial, then the inverse rotation), to ~1e-12 px.

Typical size: with ``k1 = 0.035`` and a 2° twist at the rim, a 1024² image's edge points move by
~18 px radially and ~18 px tangentially (≈5 mm at 0.29 mm/px), the order of the 6.6 mm RMS
uncorrected grid error Iaquinto et al. report for the lab's system (thesis §3.5.1).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np

from .._validate import as_points, positive
from ..geometry.camera import Camera

__all__ = ["Distortion"]


@dataclass(frozen=True)
class Distortion:
    """Pincushion + S-twist distortion of an image intensifier (see the module docs).

    Parameters
    ----------
    center : (float, float)
        Distortion centre ``(u, v)`` in pixels (the intensifier's axis in the image).
    scale_px : float
        Normalising radius in pixels (half the image's shorter side for :meth:`for_camera`).
    k1, k2 : float
        Radial coefficients, ``ρ = r (1 + k1 r² + k2 r⁴)``; ``k1 > 0`` is pincushion.
    twist_rad : float
        S-rotation at ``r = 1`` (radians, sign = sense of rotation).
    twist_power : float
        Growth of the rotation with radius, ``φ = twist_rad · r^twist_power``.
    """

    center: tuple[float, float]
    scale_px: float
    k1: float = 0.035
    k2: float = 0.0
    twist_rad: float = float(np.radians(2.0))
    twist_power: float = 2.0

    def __post_init__(self) -> None:
        c = tuple(float(x) for x in self.center)
        if len(c) != 2 or not all(np.isfinite(c)):
            raise ValueError(f"center: expected finite (u, v), got {self.center!r}")
        object.__setattr__(self, "center", c)
        positive(self.scale_px, "scale_px")
        for nm in ("k1", "k2", "twist_rad", "twist_power"):
            if not np.isfinite(getattr(self, nm)):
                raise ValueError(f"{nm}: expected a finite number, got {getattr(self, nm)!r}")
        # the radial map must be monotonic out to well beyond the image corners (r <= 2)
        r = np.linspace(0, 2.0, 401)
        if np.any(1 + 3 * self.k1 * r**2 + 5 * self.k2 * r**4 <= 0.05):
            raise ValueError(f"k1, k2: the radial map r(1 + k1 r² + k2 r⁴) folds over for r <= 2 "
                             f"(k1={self.k1}, k2={self.k2}); it must stay monotonic")
        if self.twist_power < 0:
            raise ValueError(f"twist_power: expected >= 0, got {self.twist_power}")

    # ------------------------------------------------------------------ construction
    @classmethod
    def for_camera(cls, camera: Camera, *, k1: float = 0.035, k2: float = 0.0, twist_deg: float = 2.0,
                   twist_power: float = 2.0, center_offset_px=(0.0, 0.0)) -> Distortion:
        """Distortion scaled to ``camera``'s image: centre at the image centre (+ offset), radius
        ``min(width, height) / 2``; the same parameters give the same relative distortion at
        any resolution."""
        off = np.asarray(center_offset_px, dtype=float)
        c = ((camera.width - 1) / 2 + off[0], (camera.height - 1) / 2 + off[1])
        return cls(c, min(camera.width, camera.height) / 2.0, k1, k2, float(np.radians(twist_deg)),
                   twist_power)

    @classmethod
    def random(cls, camera: Camera, rng: np.random.Generator | int = 0, *,
               k1=(0.025, 0.045), twist_deg=(1.0, 3.0), center_offset=0.02) -> Distortion:
        """Seeded plausible distortion for one view: ``k1`` and ``|twist|`` uniform in the given
        ranges, a random twist sign, and a centre offset up to ``center_offset × scale_px``."""
        g = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(rng)
        scale = min(camera.width, camera.height) / 2.0
        tw = g.uniform(*twist_deg) * g.choice([-1.0, 1.0])
        off = g.uniform(-center_offset, center_offset, size=2) * scale
        return cls.for_camera(camera, k1=g.uniform(*k1), twist_deg=tw, center_offset_px=off)

    # ------------------------------------------------------------------ maps
    def _radial(self, r):
        return r * (1.0 + self.k1 * r**2 + self.k2 * r**4)

    def _phi(self, r):
        return self.twist_rad * r**self.twist_power

    def _to_complex(self, uv) -> tuple[np.ndarray, tuple[int, ...]]:
        pts, lead = as_points(uv, "uv", 2)
        z = ((pts[:, 0] - self.center[0]) + 1j * (pts[:, 1] - self.center[1])) / self.scale_px
        return z, lead

    def _from_complex(self, z, lead) -> np.ndarray:
        w = z * self.scale_px
        return np.stack([w.real + self.center[0], w.imag + self.center[1]], -1).reshape(*lead, 2)

    def forward(self, uv) -> np.ndarray:
        """Distorted pixel positions ``(..., 2)`` of ideal positions ``uv (..., 2)`` (u, v)."""
        z, lead = self._to_complex(uv)
        r = np.abs(z)
        q = z * (1.0 + self.k1 * r**2 + self.k2 * r**4) * np.exp(1j * self._phi(r))
        return self._from_complex(q, lead)

    def inverse(self, uv) -> np.ndarray:
        """Ideal pixel positions ``(..., 2)`` of distorted positions ``uv (..., 2)`` (u, v)."""
        q, lead = self._to_complex(uv)
        rho = np.abs(q)
        r = rho.copy()
        for _ in range(50):
            f = self._radial(r) - rho
            step = f / (1.0 + 3 * self.k1 * r**2 + 5 * self.k2 * r**4)
            r -= step
            if np.all(np.abs(step) < 1e-15):
                break
        with np.errstate(invalid="ignore", divide="ignore"):
            unit = np.where(rho > 0, q / np.where(rho > 0, rho, 1.0), 0.0)
        p = unit * r * np.exp(-1j * self._phi(r))
        return self._from_complex(p, lead)

    def displacement(self, uv) -> np.ndarray:
        """``|forward(uv) - uv|`` in pixels."""
        return np.linalg.norm(self.forward(uv) - np.asarray(uv, dtype=float), axis=-1)

    # ------------------------------------------------------------------ images
    def _maps(self, shape: tuple[int, int], inverse: bool) -> tuple[np.ndarray, np.ndarray]:
        return _remap_tables(self, (int(shape[0]), int(shape[1])), bool(inverse))

    def warp(self, image: np.ndarray, *, interpolation: int = cv2.INTER_LINEAR,
             border: int = cv2.BORDER_REPLICATE) -> np.ndarray:
        """Distort an ideal image: output pixel ``q`` samples the input at ``inverse(q)``."""
        mx, my = self._maps(image.shape[:2], inverse=True)
        return cv2.remap(np.asarray(image), mx, my, interpolation, borderMode=border)

    def unwarp(self, image: np.ndarray, *, interpolation: int = cv2.INTER_LINEAR,
               border: int = cv2.BORDER_REPLICATE) -> np.ndarray:
        """Correct a distorted image: output pixel ``p`` samples the input at ``forward(p)``."""
        mx, my = self._maps(image.shape[:2], inverse=False)
        return cv2.remap(np.asarray(image), mx, my, interpolation, borderMode=border)

    def to_dict(self) -> dict:
        """JSON-ready parameters (radians, pixels)."""
        return {"model": "pincushion+s-twist", "center": list(self.center), "scale_px": self.scale_px,
                "k1": self.k1, "k2": self.k2, "twist_rad": self.twist_rad,
                "twist_power": self.twist_power}


@lru_cache(maxsize=8)
def _remap_tables(d: Distortion, shape: tuple[int, int], inverse: bool):
    """cv2.remap tables (float32, read-only), cached per distortion and image shape."""
    h, w = shape
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    src = (d.inverse if inverse else d.forward)(np.stack([u, v], axis=-1))
    mx, my = src[..., 0].astype(np.float32), src[..., 1].astype(np.float32)
    mx.setflags(write=False)
    my.setflags(write=False)
    return mx, my
