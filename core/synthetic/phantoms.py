"""Foot-bone phantoms in Hounsfield units, built from signed-distance shapes.

Anatomical ("foot CT") frame
----------------------------
All phantoms share one frame, as if segmented from a single CT of a right foot standing on the
walkway: millimetres, ``x`` anterior (towards the toes), ``y`` to the subject's left (medial for a
right foot), ``z`` up; the origin is the centre of the ankle (talocrural) joint line, just above
the talar dome; the sole rests on ``z = SOLE_Z_MM``. With ``T_lab_from_bone = FOOT_IN_LAB`` every
bone sits in the middle of :func:`~core.synthetic.rig.foot_rig`'s foot volume.

Tissue model (HU, after Schneider et al. 1996 and usual clinical CT values)
---------------------------------------------------------------------------
* cortical bone 1300–1700 HU in a shell of 0.8–1.5 mm (talus, calcaneus) thickening to ~4 mm in
  the tibial diaphysis; the shell is the band ``-t < sdf <= 0`` of the bone's signed distance;
* trabecular bone 200–400 HU plus seeded, spatially correlated texture (Gaussian-filtered white
  noise, ~1 mm correlation length, ±60–80 HU), the scale of trabecular spacing seen at 0.5 mm CT;
* marrow (medullary canals) ~30 HU, soft tissue around the bone 40 HU, air -1000 HU.

Edges are partial-volume averaged: a voxel's occupancy ramps linearly over one voxel across each
surface (``clip(0.5 - sdf / h, 0, 1)``), so the HU-weighted volume equals the shape's volume to
first order at any spacing. The soft-tissue envelope (:func:`soft_tissue_envelope`) is separate,
foot-shaped and ~40 HU, split into a foot part (moves with the calcaneus) and a shank part (moves
with the tibia) whose attenuations add up to one tissue across the ankle.

Shapes are simplified but anatomically proportioned (adult dimensions from standard anatomy
texts: talus ~60 mm long and ~30 mm wide across the trochlea, calcaneus ~80 mm long with a
posterior tuberosity, distal tibia with a ~24 mm shaft flaring to a ~45 mm plafond and a medial
malleolus, second metatarsal ~75 mm with a 9 mm shaft, a base and a rounded head).
"""

from __future__ import annotations

import zlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import gaussian_filter

from .._validate import positive
from ..render.volume import CTVolume
from . import sdf as S

__all__ = [
    "BONE_NAMES",
    "FOOT_IN_LAB",
    "SOLE_Z_MM",
    "BoneSpec",
    "Phantom",
    "bone_centroid",
    "bone_phantom",
    "bone_spec",
    "foot_phantoms",
    "hu_from_sdf",
    "soft_tissue_envelope",
    "voxel_grid",
]

BONE_NAMES = ("tibia", "talus", "calcaneus", "metatarsal2")
SOLE_Z_MM = -85.0
#: Rigid placement of the anatomical frame in the lab of :func:`~core.synthetic.rig.foot_rig`
#: (a pure translation: hindfoot near the lab origin, the sole on the walkway at z = -85 mm).
FOOT_IN_LAB = np.array([[1, 0, 0, -25.0], [0, 1, 0, 0.0], [0, 0, 1, 0.0], [0, 0, 0, 1]])

AIR_HU, SOFT_HU, MARROW_HU = -1000.0, 40.0, 30.0


@dataclass(frozen=True, eq=False)
class BoneSpec:
    """Shape and tissue parameters of one bone (mm, HU).

    ``cortex_mm`` is a constant or a callable of points (N, 3) → (N,) thickness; ``canal`` is an
    optional SDF of a marrow cavity; ``search`` the (lo, hi) box searched for the bone's extent.
    """

    name: str
    shape: S.SDF
    cortex_mm: float | Callable[[np.ndarray], np.ndarray]
    cortical_hu: float
    trabecular_hu: float
    texture_hu: float
    search: tuple[tuple[float, float, float], tuple[float, float, float]]
    canal: S.SDF | None = None


@dataclass(frozen=True, eq=False)
class Phantom:
    """A voxelised bone and its ground truth.

    Attributes
    ----------
    volume : CTVolume
        HU, physical frame = the anatomical frame above.
    sdf : callable
        Ground-truth signed distance (mm) of the outer bone surface in that frame.
    spec : BoneSpec
    """

    volume: CTVolume
    sdf: S.SDF
    spec: BoneSpec

    @property
    def name(self) -> str:
        return self.volume.name


def _talus_shape() -> S.SDF:
    body = S.Ellipsoid((-3, 0, -15), (21, 15, 12))
    trochlea = S.Intersection([S.Capsule((-3, -14, -31), (-3, 14, -31), 30.0),
                               S.Box((-3, 0, -12), (20, 14, 12), rounding=3.0)])
    neck_head = S.RoundCone((12, 4, -15), (30, 8, -19), 9.0, 11.5)
    return S.SmoothUnion([body, trochlea, neck_head], k=6.0)


def _tibia_shape(talus: S.SDF, gap: float = 2.5) -> S.SDF:
    shaft = S.RoundCone((0, 2, 30), (-2, 0, 115), 13.0, 11.5)
    flare = S.Ellipsoid((1, 2, 8), (19, 22, 16))
    malleolus = S.Capsule((2, 19, 10), (4, 20, -14), 6.5)
    bone = S.SmoothUnion([shaft, flare, malleolus], k=8.0)
    floor = S.Box((0, 0, -100), (200, 200, 100.5))  # clip everything below z = 0.5 ...
    cut = S.Intersection([floor, S.Box((0, 0, 0), (200, 12, 200))])  # ... except the malleolus
    bone = S.Subtraction(bone, cut)
    return S.Subtraction(bone, lambda p: talus(p) - gap)  # joint space to the talus


def _calcaneus_shape(talus: S.SDF, gap: float = 2.0) -> S.SDF:
    body = S.Box((-8, -3, -48), (30, 16, 16), rounding=9.0)
    tuber = S.Ellipsoid((-40, -3, -47), (14, 17, 21))
    anterior = S.RoundCone((14, -6, -43), (26, -8, -41), 11.0, 12.0)
    sustentaculum = S.Capsule((-2, 12, -34), (8, 18, -36), 5.0)
    bone = S.SmoothUnion([body, tuber, anterior, sustentaculum], k=6.0)
    return S.Subtraction(bone, lambda p: talus(p) - gap)


def _metatarsal_parts() -> tuple[S.SDF, S.SDF]:
    base, head = np.array([76.0, 8, -48]), np.array([136.0, 11, -70])
    d = (head - base) / np.linalg.norm(head - base)
    y = np.cross([0.0, 0, 1], d)
    y /= np.linalg.norm(y)
    R = np.column_stack([d, y, np.cross(d, y)])  # local x along the shaft
    shaft = S.RoundCone(base + 6 * d, head - 6 * d, 5.0, 4.2)
    b = S.transformed(S.Ellipsoid((0, 0, 0), (8, 7, 10)), rotation=R, translation=base)
    h = S.transformed(S.Ellipsoid((0, 0, 0), (7.5, 5.5, 7)), rotation=R, translation=head)
    canal = S.RoundCone(base + 14 * d, head - 14 * d, 2.0, 1.8)
    return S.SmoothUnion([b, shaft, h], k=5.0), canal


def _smoothstep(x):
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3 - 2 * x)


def bone_spec(name: str) -> BoneSpec:
    """The :class:`BoneSpec` of one of :data:`BONE_NAMES`."""
    talus = _talus_shape()
    if name == "talus":
        return BoneSpec(name, talus, 1.0, 1400.0, 380.0, 70.0, ((-30, -25, -40), (50, 25, 5)))
    if name == "tibia":
        def cortex(p):  # ~1.5 mm at the plafond, ~4 mm in the diaphysis
            return 1.5 + 2.5 * _smoothstep((p[:, 2] - 25.0) / 50.0)

        canal = S.RoundCone((-1, 1, 55), (-2, 0, 125), 6.0, 7.0)
        return BoneSpec(name, _tibia_shape(talus), cortex, 1700.0, 260.0, 70.0,
                        ((-30, -30, -25), (30, 35, 120)), canal=canal)
    if name == "calcaneus":
        return BoneSpec(name, _calcaneus_shape(talus), 0.9, 1300.0, 240.0, 60.0,
                        ((-75, -30, -80), (55, 30, -20)))
    if name == "metatarsal2":
        shape, canal = _metatarsal_parts()
        return BoneSpec(name, shape, 1.4, 1600.0, 320.0, 60.0,
                        ((60, -10, -85), (150, 25, -30)), canal=canal)
    raise ValueError(f"name: expected one of {BONE_NAMES}, got {name!r}")


def voxel_grid(lo, hi, spacing: float) -> tuple[np.ndarray, np.ndarray, tuple[int, int, int]]:
    """Voxel centres covering the box ``[lo, hi]`` (mm) at ``spacing``.

    Returns ``(origin (3,), points (nz, ny, nx, 3), (nx, ny, nz))``; ``origin`` is the centre of
    voxel (0, 0, 0) and the grid is centred on the box.
    """
    lo, hi = np.asarray(lo, dtype=float), np.asarray(hi, dtype=float)
    n = np.maximum(np.ceil((hi - lo) / spacing).astype(int), 1)
    origin = (lo + hi) / 2 - (n - 1) * spacing / 2
    axes = [origin[a] + spacing * np.arange(n[a]) for a in range(3)]
    z, y, x = np.meshgrid(axes[2], axes[1], axes[0], indexing="ij")
    return origin, np.stack([x, y, z], axis=-1), (int(n[0]), int(n[1]), int(n[2]))


def _extent(shape: S.SDF, search, margin: float, step: float = 2.0):
    _, pts, _ = voxel_grid(search[0], search[1], step)
    d = S.sample_sdf(shape, pts)
    inside = d < step
    if not inside.any():
        raise ValueError("shape: no part of the shape lies inside its search box")
    p = pts[inside]
    return p.min(axis=0) - margin - step, p.max(axis=0) + margin + step


def _occupancy(d: np.ndarray, h: float) -> np.ndarray:
    return np.clip(0.5 - d / h, 0.0, 1.0)


def hu_from_sdf(
    d: np.ndarray,
    *,
    voxel_mm: float,
    cortex_mm: np.ndarray | float,
    cortical_hu: float,
    trabecular_hu: np.ndarray | float,
    background_hu: float = SOFT_HU,
    canal_sdf: np.ndarray | None = None,
    marrow_hu: float = MARROW_HU,
) -> np.ndarray:
    """HU of voxels from their signed distance ``d`` (mm) to the outer bone surface.

    ``background + (cortical - background)·occ(d) + (trabecular - cortical)·occ(d + cortex)``,
    with ``occ(s) = clip(0.5 - s / voxel_mm, 0, 1)`` (partial-volume ramp over one voxel), and
    the marrow cavity (``canal_sdf < 0``) replacing trabecular bone the same way.
    """
    outer = _occupancy(d, voxel_mm)
    inner = _occupancy(d + cortex_mm, voxel_mm)
    hu = background_hu + (cortical_hu - background_hu) * outer + (trabecular_hu - cortical_hu) * inner
    if canal_sdf is not None:
        hu = hu + (marrow_hu - trabecular_hu) * inner * _occupancy(canal_sdf, voxel_mm)
    return hu


def _texture(shape: tuple[int, ...], spacing: float, rng: np.random.Generator) -> np.ndarray:
    """Unit-variance Gaussian noise, ~1 mm correlation length (>= 1 voxel), clipped to ±2 σ."""
    n = rng.standard_normal(shape).astype(np.float32)
    sigma = max(0.5 / spacing, 0.5)
    t = gaussian_filter(n, sigma, mode="wrap")
    return np.clip(t / max(float(t.std()), 1e-6), -2.0, 2.0)


def _bone_seed(seed: int, name: str) -> list[int]:
    return [int(seed), zlib.crc32(name.encode())]


def bone_phantom(
    name: str, *, spacing: float = 0.5, seed: int = 0, margin_mm: float = 3.0, dtype=np.int16
) -> Phantom:
    """Voxelise one bone of :data:`BONE_NAMES` as a :class:`Phantom` in HU.

    Parameters
    ----------
    name : str
    spacing : float
        Isotropic voxel size, mm (0.5 like a clinical foot CT; 2–4 mm for fast tests).
    seed : int
        Seed of the trabecular texture (per bone: the same ``seed`` gives each bone its own,
        reproducible texture).
    margin_mm : float
        Soft tissue kept around the bone's bounding box, mm.
    dtype : numpy dtype
        ``np.int16`` (rounded HU, as CT files store them) or ``np.float32``.
    """
    spacing = positive(spacing, "spacing")
    spec = bone_spec(name)
    lo, hi = _extent(spec.shape, spec.search, margin_mm)
    origin, pts, _ = voxel_grid(lo, hi, spacing)
    flat = pts.reshape(-1, 3)
    d = S.sample_sdf(spec.shape, flat)
    cortex = spec.cortex_mm(flat) if callable(spec.cortex_mm) else spec.cortex_mm
    rng = np.random.default_rng(_bone_seed(seed, name))
    tex = _texture(pts.shape[:3], spacing, rng).reshape(-1)
    canal = None if spec.canal is None else S.sample_sdf(spec.canal, flat)
    hu = hu_from_sdf(
        d, voxel_mm=spacing, cortex_mm=cortex, cortical_hu=spec.cortical_hu,
        trabecular_hu=spec.trabecular_hu + spec.texture_hu * tex, canal_sdf=canal,
    ).reshape(pts.shape[:3])
    data = np.rint(hu).astype(dtype) if np.issubdtype(np.dtype(dtype), np.integer) else hu.astype(dtype)
    vol = CTVolume(data, spacing=np.full(3, spacing), origin=origin, units="HU", name=name)
    return Phantom(vol, spec.shape, spec)


def foot_phantoms(
    names: Sequence[str] = BONE_NAMES, *, spacing: float = 0.5, seed: int = 0, dtype=np.int16
) -> list[Phantom]:
    """:func:`bone_phantom` for each of ``names`` (default: tibia, talus, calcaneus, metatarsal)."""
    return [bone_phantom(n, spacing=spacing, seed=seed, dtype=dtype) for n in names]


def _envelope_shape() -> S.SDF:
    hind = S.Ellipsoid((-35, -2, -48), (40, 34, 37))
    mid = S.Ellipsoid((50, 5, -52), (60, 42, 30))
    fore = S.Ellipsoid((128, 10, -70), (36, 45, 15))
    shank = S.Capsule((-5, 0, -30), (-10, 0, 150), 36.0)
    foot = S.SmoothUnion([hind, mid, fore, shank], k=15.0)
    sole = S.Box((0, 0, SOLE_Z_MM + 150), (300, 300, 150))  # flattened on the walkway
    return S.Intersection([foot, sole])


def soft_tissue_envelope(
    *, spacing: float = 2.0, hu: float = SOFT_HU, split_z_mm: float = 0.0, blend_mm: float = 30.0,
    top_z_mm: float = 140.0,
) -> tuple[CTVolume, CTVolume]:
    """Foot-shaped soft tissue (``hu``, default 40 HU) as ``(foot part, shank part)`` volumes.

    The two parts share the anatomical frame and split the tissue's *attenuation* with weights
    ``w`` and ``1 - w`` that blend smoothly over ``blend_mm`` around ``z = split_z_mm``: a voxel
    stores ``HU = -1000 + w·occupancy·(1000 + hu)``, so with the linear HU → μ transfer the two
    parts add up to the tissue's μ. Attach the foot part to the calcaneus and the shank part to
    the tibia; as the ankle flexes the seam deforms smoothly instead of tearing.

    Returns float32 volumes in HU (air -1000 outside the skin), names ``"soft_foot"`` and
    ``"soft_shank"``.
    """
    spacing = positive(spacing, "spacing")
    shape, origin, pts = _envelope_grid(spacing, top_z_mm)
    occ = _occupancy(S.sample_sdf(shape, pts), spacing)
    return _foot_and_shank(occ, 1000.0 + hu, pts, origin, spacing, split_z_mm, blend_mm)


def _envelope_grid(spacing: float, top_z_mm: float):
    """The envelope's SDF and the grid around it up to ``top_z_mm``: ``(shape, origin, voxel
    centres)``."""
    shape = _envelope_shape()
    lo, hi = _extent(shape, ((-110, -70, -90), (190, 70, top_z_mm)), 2.0, step=4.0)
    hi[2] = min(hi[2], top_z_mm)
    origin, pts, _ = voxel_grid(lo, hi, spacing)
    return shape, origin, pts


def _foot_and_shank(occ, contrast, pts, origin, spacing: float, split_z_mm: float,
                    blend_mm: float) -> tuple[CTVolume, CTVolume]:
    """The foot and shank parts of soft tissue of occupancy ``occ`` and ``contrast`` (HU above
    air): ``HU = -1000 + w·occ·contrast``, ``w`` blending over ``blend_mm`` about ``split_z_mm``."""
    w_shank = _smoothstep((pts[..., 2] - split_z_mm) / blend_mm + 0.5)
    vols = []
    for nm, w in (("soft_foot", 1.0 - w_shank), ("soft_shank", w_shank)):
        data = (AIR_HU + w * occ * contrast).astype(np.float32)
        vols.append(CTVolume(data, spacing=np.full(3, spacing), origin=origin, units="HU", name=nm))
    return vols[0], vols[1]


_CENTROIDS: dict[str, np.ndarray] = {}


def bone_centroid(name: str) -> np.ndarray:
    """Centroid (mm, anatomical frame) of the solid bone ``name`` (1 mm sampling of its SDF)."""
    if name not in _CENTROIDS:
        spec = bone_spec(name)
        _, pts, _ = voxel_grid(*_extent(spec.shape, spec.search, 0.0), 1.0)
        d = S.sample_sdf(spec.shape, pts)
        w = _occupancy(d, 1.0)
        _CENTROIDS[name] = (pts * w[..., None]).reshape(-1, 3).sum(axis=0) / w.sum()
    return _CENTROIDS[name].copy()
