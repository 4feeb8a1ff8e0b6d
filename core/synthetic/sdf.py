"""Signed-distance primitives and compositions for building bone and soft-tissue phantoms.

A shape is a callable ``sdf(points (N, 3) mm) -> (N,) mm``: negative inside, zero on the surface,
positive outside. Sphere, capsule, round cone, rounded box and half-space distances are exact
Euclidean distances; the ellipsoid uses the first-order bound of Quílez ("ellipsoid SDF",
iquilezles.org), exact on the surface and within a few per cent of the true distance in the
millimetre band used for cortical shells. Unions/intersections by ``min``/``max`` keep exact
distances outside (union) or inside (intersection); the *smooth* union (polynomial ``smin``)
blends two shapes within ``k`` mm and is a lower bound of the distance, so shells built from it
are slightly thicker where shapes meet, like real metaphyseal flares.

Every shape is a small frozen dataclass; :func:`transformed` places a shape with a 4x4 rigid
transform (``T_parent_from_shape``).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from .._validate import as_float_array, check_rigid

__all__ = [
    "SDF",
    "Box",
    "Capsule",
    "Ellipsoid",
    "Intersection",
    "RoundCone",
    "SmoothUnion",
    "Sphere",
    "Subtraction",
    "Transformed",
    "Union",
    "sample_sdf",
    "transformed",
]

SDF = Callable[[np.ndarray], np.ndarray]


def _vec(v, name: str) -> np.ndarray:
    return as_float_array(v, name, shape=(3,))


@dataclass(frozen=True, eq=False)
class Sphere:
    """Ball of ``radius`` mm about ``center``."""

    center: Sequence[float]
    radius: float

    def __call__(self, p: np.ndarray) -> np.ndarray:
        return np.linalg.norm(p - _vec(self.center, "center"), axis=-1) - self.radius


@dataclass(frozen=True, eq=False)
class Ellipsoid:
    """Axis-aligned ellipsoid with semi-axes ``radii`` (mm) about ``center`` (Quílez bound)."""

    center: Sequence[float]
    radii: Sequence[float]

    def __call__(self, p: np.ndarray) -> np.ndarray:
        r = _vec(self.radii, "radii")
        q = p - _vec(self.center, "center")
        k0 = np.linalg.norm(q / r, axis=-1)
        k1 = np.linalg.norm(q / (r * r), axis=-1)
        with np.errstate(divide="ignore", invalid="ignore"):
            d = k0 * (k0 - 1.0) / k1
        return np.where(k1 > 0, d, -r.min())


@dataclass(frozen=True, eq=False)
class RoundCone:
    """Exact distance to the convex hull of two balls ``(a, ra)`` and ``(b, rb)`` (mm).

    With ``ra == rb`` this is a capsule. Formula after Quílez ("round cone").
    """

    a: Sequence[float]
    b: Sequence[float]
    ra: float
    rb: float

    def __call__(self, p: np.ndarray) -> np.ndarray:
        a, b = _vec(self.a, "a"), _vec(self.b, "b")
        r1, r2 = float(self.ra), float(self.rb)
        ba = b - a
        l2 = ba @ ba
        rr = r1 - r2
        a2 = l2 - rr * rr
        il2 = 1.0 / l2
        pa = p - a
        y = pa @ ba
        z = y - l2
        xv = pa * l2 - y[:, None] * ba
        x2 = np.einsum("ij,ij->i", xv, xv)
        y2 = y * y * l2
        z2 = z * z * l2
        k = np.sign(rr) * rr * rr * x2
        out = (np.sqrt(x2 * a2 * il2) + y * rr) * il2 - r1
        d_b = np.sqrt(x2 + z2) * il2 - r2
        d_a = np.sqrt(x2 + y2) * il2 - r1
        out = np.where(np.sign(y) * a2 * y2 < k, d_a, out)
        out = np.where(np.sign(z) * a2 * z2 > k, d_b, out)
        return out


def Capsule(a, b, radius: float) -> RoundCone:
    """Segment ``a``–``b`` swept by a ball of ``radius`` mm."""
    return RoundCone(a, b, radius, radius)


@dataclass(frozen=True, eq=False)
class Box:
    """Box of half-extents ``half`` (mm) about ``center``, edges rounded by ``rounding`` mm."""

    center: Sequence[float]
    half: Sequence[float]
    rounding: float = 0.0

    def __call__(self, p: np.ndarray) -> np.ndarray:
        h = _vec(self.half, "half") - self.rounding
        q = np.abs(p - _vec(self.center, "center")) - h
        outside = np.linalg.norm(np.maximum(q, 0.0), axis=-1)
        inside = np.minimum(q.max(axis=-1), 0.0)
        return outside + inside - self.rounding


@dataclass(frozen=True, eq=False)
class Union:
    """Hard union ``min`` of shapes."""

    shapes: Sequence[SDF]

    def __call__(self, p: np.ndarray) -> np.ndarray:
        return np.min([s(p) for s in self.shapes], axis=0)


@dataclass(frozen=True, eq=False)
class SmoothUnion:
    """Polynomial smooth union (``smin`` with blend width ``k`` mm), folded left to right."""

    shapes: Sequence[SDF]
    k: float = 4.0

    def __call__(self, p: np.ndarray) -> np.ndarray:
        it = iter(self.shapes)
        d = next(it)(p)
        for s in it:
            e = s(p)
            h = np.maximum(self.k - np.abs(d - e), 0.0) / self.k
            d = np.minimum(d, e) - h * h * self.k * 0.25
        return d


@dataclass(frozen=True, eq=False)
class Intersection:
    """Hard intersection ``max`` of shapes."""

    shapes: Sequence[SDF]

    def __call__(self, p: np.ndarray) -> np.ndarray:
        return np.max([s(p) for s in self.shapes], axis=0)


@dataclass(frozen=True, eq=False)
class Subtraction:
    """``base`` minus ``cut``: ``max(base, -cut)``."""

    base: SDF
    cut: SDF

    def __call__(self, p: np.ndarray) -> np.ndarray:
        return np.maximum(self.base(p), -self.cut(p))


@dataclass(frozen=True, eq=False)
class Transformed:
    """``shape`` placed in its parent frame by the rigid ``T_parent_from_shape`` (4x4)."""

    shape: SDF
    T_parent_from_shape: np.ndarray

    def __call__(self, p: np.ndarray) -> np.ndarray:
        T = check_rigid(self.T_parent_from_shape, "T_parent_from_shape")
        local = (p - T[:3, 3]) @ T[:3, :3]  # R^T (p - t)
        return self.shape(local)


def transformed(shape: SDF, *, rotation=None, translation=(0.0, 0.0, 0.0)) -> Transformed:
    """Place ``shape`` with a rotation matrix (3x3, default identity) and translation (mm)."""
    T = np.eye(4)
    if rotation is not None:
        T[:3, :3] = as_float_array(rotation, "rotation", shape=(3, 3))
    T[:3, 3] = _vec(translation, "translation")
    return Transformed(shape, T)


def sample_sdf(shape: SDF, points, *, chunk: int = 1 << 20) -> np.ndarray:
    """Evaluate ``shape`` at ``points (..., 3)`` mm in chunks; returns ``(...)`` float64 mm."""
    pts = as_float_array(points, "points")
    if pts.shape[-1] != 3:
        raise ValueError(f"points: expected shape (..., 3), got {pts.shape}")
    flat = pts.reshape(-1, 3)
    out = np.empty(len(flat))
    for s in range(0, len(flat), chunk):
        out[s : s + chunk] = shape(flat[s : s + chunk])
    return out.reshape(pts.shape[:-1])
