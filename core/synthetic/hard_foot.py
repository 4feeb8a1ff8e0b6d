"""A harder synthetic foot trial: detailed bone shapes, trabecular networks, layered soft tissue,
untracked neighbours, and a CT that is not the truth.

:func:`make_foot_scene` builds its bones from a few smooth primitives with a faint texture and
renders the frames from the very volumes the tracker registers, so the cost's optimum lies
exactly at the truth. Real trials differ in five ways, each reproduced here:

* **Shapes** (:func:`hard_bone_spec`) — the talus has a grooved trochlea, lateral and posterior
  processes, a neck, a medially turned head, a sulcus tali and a concave posterior facet; the
  calcaneus a tuberosity with medial and lateral processes, a sustentaculum, a peroneal
  tubercle, an anterior process and facets carved by the talus; the distal tibia a triangular
  shaft with an anterior crest, a flared plafond carved by the talus, a medial malleolus and a
  fibular notch. Proportions follow standard adult anatomy (talus ~65 mm long, calcaneus ~90 mm,
  tibial plafond ~45 mm wide); joint spaces 2.5 mm (talocrural) and 2.0 mm (subtalar).
* **Neighbours** — the fibula (lateral malleolus beside the talus) and the navicular (in front of
  the talar head) are in every frame but not tracked: structures that overlap the tracked bones'
  projections and that no model accounts for.
* **Trabecular bone** (:func:`trabecular_network`) — a plate-and-rod network, not a faint noise:
  the zero set of band-pass (difference-of-Gaussians) noise, stretched along the bone's main load
  axis, thickened to a bone volume fraction of 0.18–0.30 and mixed with marrow, denser under the
  articular surfaces (subchondral bone) and sparse in the calcaneus' neutral triangle. At 0.5–1 mm
  voxels this gives ±200–300 HU of texture around 250–350 HU, the look of a clinical foot CT.
* **Cortex** — 0.5–1.5 mm (tibial diaphysis to 4 mm) with a seeded ±30 % low-frequency variation.
* **Soft tissue** (:func:`layered_tissue`) — a fat layer (-90 HU, 5 mm under the skin) around
  muscle and tendon (50 HU) with the Achilles tendon (90 HU) behind the ankle; split into a foot
  part and a shank part like :func:`~core.synthetic.phantoms.soft_tissue_envelope`.
* **The CT is not the truth** (:func:`ct_of`) — the tracker's bone volumes are the truth as a CT
  scanner would record it: blurred by a Gaussian point-spread function (0.35 mm σ), resampled on a
  grid offset by a fraction of a voxel, with 12 HU of noise and rounded to integer HU. The frames
  are rendered from the truth, so the cost's optimum no longer sits exactly at the truth.

Everything is seeded. The anatomical frame and its placement in the lab are those of
:mod:`core.synthetic.phantoms`; tracked bones move as in :func:`~core.synthetic.motion.stance_trajectories`
(with a smaller jitter, so the truth's bones never touch), the fibula with the tibia, the navicular
with the talus (plus a few degrees of talonavicular rotation).
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass, replace

import numpy as np
from scipy.ndimage import gaussian_filter, map_coordinates

from .._validate import positive
from ..render.volume import CTVolume
from . import sdf as S
from .phantoms import (
    AIR_HU,
    BoneSpec,
    _envelope_grid,
    _extent,
    _foot_and_shank,
    _occupancy,
    _smoothstep,
    hu_from_sdf,
    voxel_grid,
)

__all__ = ["HARD_BONES", "NEIGHBOURS", "HardFootTrial", "ct_of", "hard_bone_phantom", "hard_bone_spec",
           "layered_tissue", "make_hard_foot_scene", "trabecular_network"]

HARD_BONES = ("tibia", "talus", "calcaneus")
NEIGHBOURS = ("fibula", "navicular")
MARROW_HU, TRABECULA_HU = 20.0, 1150.0


def _talus() -> S.SDF:
    body = S.Ellipsoid((-3, 0, -15), (20, 14.5, 11.5))
    trochlea = S.Intersection([S.Capsule((-3, -14, -31), (-3, 14, -31), 30.0),
                               S.Box((-3, 0, -12), (19, 13.5, 12), rounding=3.0)])
    lateral = S.RoundCone((-4, -12, -19), (-2, -19, -28), 6.0, 3.0)
    post_lat = S.RoundCone((-17, -5, -19), (-26, -7, -24), 6.0, 3.0)
    post_med = S.RoundCone((-17, 6, -19), (-24, 8, -24), 5.0, 2.5)
    neck = S.RoundCone((10, 3, -15), (24, 7, -18), 8.5, 8.0)
    head = S.Ellipsoid((31, 9, -20), (10, 13, 10.5))
    bone = S.SmoothUnion([body, trochlea, lateral, post_lat, post_med, neck, head], k=4.0)
    groove = S.Capsule((-30, 1, 2.0), (25, 1, 2.0), 3.5)  # the trochlea's central groove
    sulcus = S.Capsule((8, -22, -29), (2, 16, -27), 4.0)  # sulcus tali / sinus tarsi
    facet = S.Capsule((-22, -20, -36.5), (8, 16, -36.5), 10.0)  # concave posterior facet
    fhl = S.Capsule((-24, 1, -10), (-24, 1, -34), 2.2)  # groove between the posterior tubercles
    for cut in (groove, sulcus, facet, fhl):
        bone = S.Subtraction(bone, cut)
    return bone


def _tibia(talus: S.SDF, gap: float = 2.5) -> S.SDF:
    # a rounded triangle in cross-section: the shaft's three borders (anterior crest, interosseous)
    shaft = S.RoundCone((0, 2, 30), (-2, 0, 125), 12.0, 10.5)
    crest = S.RoundCone((9, 2, 35), (8, 0, 125), 5.0, 4.5)
    interosseous = S.RoundCone((-3, -9, 35), (-3, -8, 125), 5.5, 4.5)
    flare = S.Ellipsoid((1, 2, 8), (19, 22, 16))
    anterior_lip = S.Ellipsoid((14, 1, 2), (6, 16, 6))
    malleolus = S.RoundCone((2, 19, 12), (5, 20, -14), 7.0, 5.0)
    bone = S.SmoothUnion([shaft, crest, interosseous, flare, anterior_lip, malleolus], k=7.0)
    floor = S.Box((0, 0, -100), (200, 200, 100.5))
    cut = S.Intersection([floor, S.Box((0, 0, 0), (200, 12, 200))])  # keep the malleolus
    bone = S.Subtraction(bone, cut)
    notch = S.Capsule((-7, -26, -5), (-6, -24, 60), 8.5)  # the fibular notch
    bone = S.Subtraction(bone, notch)
    return S.Subtraction(bone, lambda p: talus(p) - gap)


def _fibula(talus: S.SDF, tibia: S.SDF) -> S.SDF:
    shaft = S.RoundCone((-9, -25, 20), (-11, -24, 125), 7.0, 6.0)
    malleolus = S.RoundCone((-8, -26, 18), (-9, -27, -22), 9.5, 6.0)
    bone = S.SmoothUnion([shaft, malleolus], k=6.0)
    bone = S.Subtraction(bone, lambda p: talus(p) - 2.5)
    return S.Subtraction(bone, lambda p: tibia(p) - 1.5)


def _calcaneus(talus: S.SDF, gap: float = 2.0) -> S.SDF:
    body = S.Box((-8, -3, -48), (30, 15, 15), rounding=8.0)
    tuber = S.Ellipsoid((-40, -3, -46), (13, 16, 20))
    proc_med = S.Ellipsoid((-42, 6, -63), (10, 8, 6))
    proc_lat = S.Ellipsoid((-40, -10, -63), (8, 6, 5))
    anterior = S.RoundCone((12, -6, -43), (27, -8, -41), 10.5, 11.5)
    sustentaculum = S.RoundCone((-4, 11, -33), (8, 19, -36), 5.5, 4.0)
    peroneal = S.Ellipsoid((2, -17, -50), (6, 3, 3))
    bone = S.SmoothUnion([body, tuber, proc_med, proc_lat, anterior, sustentaculum, peroneal], k=5.0)
    fhl = S.Capsule((-20, 16, -42), (15, 22, -45), 3.0)  # groove under the sustentaculum
    bone = S.Subtraction(bone, fhl)
    return S.Subtraction(bone, lambda p: talus(p) - gap)


def _navicular(talus: S.SDF, gap: float = 2.0) -> S.SDF:
    bone = S.SmoothUnion([S.Ellipsoid((49, 11, -22), (8, 17, 14)),
                          S.Ellipsoid((48, 24, -30), (6, 6, 6))], k=4.0)  # the tuberosity
    return S.Subtraction(bone, lambda p: talus(p) - gap)


@dataclass(frozen=True, eq=False)
class HardBoneSpec:
    """A :class:`~core.synthetic.phantoms.BoneSpec` plus the trabecular network's parameters:
    bone volume fraction ``bvf``, network spacing ``spacing_mm`` and the direction ``axis`` of
    its anisotropy (the main load axis, anatomical frame), ``voids`` (SDFs of sparse regions)."""

    base: BoneSpec
    bvf: float
    spacing_mm: float
    axis: tuple[float, float, float]
    voids: tuple = ()


def hard_bone_spec(name: str) -> HardBoneSpec:
    """The spec of one of :data:`HARD_BONES` + :data:`NEIGHBOURS` (shapes in the module docs)."""
    talus = _talus()
    if name == "talus":
        return HardBoneSpec(BoneSpec(name, talus, 0.8, 1400.0, 0.0, 0.0, ((-35, -28, -42), (48, 28, 5))),
                            0.30, 1.6, (0.0, 0.0, 1.0))
    if name == "tibia":
        def cortex(p):
            return 1.2 + 2.8 * _smoothstep((p[:, 2] - 25.0) / 50.0)

        canal = S.RoundCone((-1, 1, 55), (-2, 0, 125), 6.0, 7.0)
        spec = BoneSpec(name, _tibia(talus), cortex, 1700.0, 0.0, 0.0, ((-30, -30, -25), (30, 35, 120)),
                        canal=canal)
        return HardBoneSpec(spec, 0.22, 1.8, (0.0, 0.0, 1.0))
    if name == "calcaneus":
        void = S.Ellipsoid((4, -3, -46), (9, 9, 7))  # the neutral triangle
        return HardBoneSpec(BoneSpec(name, _calcaneus(talus), 0.7, 1300.0, 0.0, 0.0,
                                     ((-75, -30, -80), (55, 30, -20))), 0.20, 1.8, (-0.6, 0.0, 0.8), (void,))
    if name == "fibula":
        return HardBoneSpec(BoneSpec(name, _fibula(talus, _tibia(talus)), 1.2, 1600.0, 0.0, 0.0,
                                     ((-30, -45, -40), (15, -5, 120))), 0.22, 1.8, (0.0, 0.0, 1.0))
    if name == "navicular":
        return HardBoneSpec(BoneSpec(name, _navicular(talus), 0.7, 1300.0, 0.0, 0.0,
                                     ((30, -15, -45), (65, 40, 0))), 0.28, 1.6, (1.0, 0.0, 0.0))
    raise ValueError(f"name: expected one of {HARD_BONES + NEIGHBOURS}, got {name!r}")


def _seed(seed: int, name: str, what: str) -> list[int]:
    return [int(seed), zlib.crc32(name.encode()), zlib.crc32(what.encode())]


def _smooth_noise(shape, sigma_vox, rng: np.random.Generator) -> np.ndarray:
    t = gaussian_filter(rng.standard_normal(shape).astype(np.float32), sigma_vox, mode="wrap")
    return t / max(float(t.std()), 1e-6)


def trabecular_network(shape_kji, voxel_mm: float, rng: np.random.Generator, *, spacing_mm: float = 1.2,
                       bvf: float = 0.25, axis=(0.0, 0.0, 1.0), stretch: float = 1.8) -> np.ndarray:
    """Bone volume fraction ``(nk, nj, ni)`` in [0, 1] of a plate-and-rod network.

    The network is the neighbourhood of the zero set of band-pass noise (a difference of two
    Gaussian filters of white noise whose scales bracket ``spacing_mm``), stretched ``stretch``×
    along the voxel axis closest to ``axis``; its width is set so that the mean fraction is
    ``bvf``. Filter widths below half a voxel are raised to half a voxel (a coarse grid sees the
    network partial-volume averaged).
    """
    ax = int(np.argmax(np.abs(axis)))  # x, y, z -> data axis 2, 1, 0
    a = np.ones(3)
    a[2 - ax] = stretch
    s1 = np.maximum(0.18 * spacing_mm / voxel_mm * a, 0.6)
    s2 = np.maximum(0.45 * spacing_mm / voxel_mm * a, 1.4)
    n = rng.standard_normal(shape_kji).astype(np.float32)
    band = gaussian_filter(n, s1, mode="wrap") - gaussian_filter(n, s2, mode="wrap")
    band /= max(float(band.std()), 1e-6)
    # |band| < w covers a fraction erf(w / sqrt 2) of a standard normal: choose w for the fraction
    from scipy.special import erfinv

    w = float(np.sqrt(2.0) * erfinv(min(max(bvf, 0.01), 0.95)))
    frac = np.clip((w - np.abs(band)) / (0.5 * w) + 0.5, 0.0, 1.0)
    return gaussian_filter(frac, max(0.25 / voxel_mm, 0.3))


def hard_bone_phantom(name: str, *, spacing: float = 0.5, seed: int = 0, margin_mm: float = 3.0):
    """Voxelise one bone of :func:`hard_bone_spec` (float32 HU, truth: no CT blur or noise).

    Returns a :class:`~core.synthetic.phantoms.Phantom`."""
    from .phantoms import Phantom

    spacing = positive(spacing, "spacing")
    hs = hard_bone_spec(name)
    spec = hs.base
    lo, hi = _extent(spec.shape, spec.search, margin_mm)
    origin, pts, _ = voxel_grid(lo, hi, spacing)
    flat = pts.reshape(-1, 3)
    d = S.sample_sdf(spec.shape, flat)
    shape = pts.shape[:3]
    g = np.random.default_rng(_seed(seed, name, "network"))
    net = trabecular_network(shape, spacing, g, spacing_mm=hs.spacing_mm, bvf=hs.bvf, axis=hs.axis)
    net = net.reshape(-1)
    # subchondral densification within 3 mm of the surface, sparse voids
    dens = 1.0 + 0.6 * np.clip(1.0 + d / 3.0, 0.0, 1.0)
    for v in hs.voids:
        dens = dens * (0.35 + 0.65 * _smoothstep(S.sample_sdf(v, flat) / 3.0 + 0.5))
    frac = np.clip(net * dens, 0.0, 1.0)
    trab = MARROW_HU + (TRABECULA_HU - MARROW_HU) * frac
    var = _smooth_noise(shape, max(6.0 / spacing, 1.0), np.random.default_rng(_seed(seed, name, "cortex")))
    base = spec.cortex_mm(flat) if callable(spec.cortex_mm) else spec.cortex_mm
    cortex = np.maximum(base * (1.0 + 0.3 * np.clip(var.reshape(-1), -1.5, 1.5)), 0.4)
    canal = None if spec.canal is None else S.sample_sdf(spec.canal, flat)
    hu = hu_from_sdf(d, voxel_mm=spacing, cortex_mm=cortex, cortical_hu=spec.cortical_hu,
                     trabecular_hu=trab, canal_sdf=canal).reshape(shape)
    vol = CTVolume(hu.astype(np.float32), spacing=np.full(3, spacing), origin=origin, units="HU", name=name)
    return Phantom(vol, spec.shape, spec)


def ct_of(volume: CTVolume, *, seed: int = 0, psf_mm: float = 0.35, noise_hu: float = 12.0,
          offset_vox=(0.37, 0.21, 0.45)) -> CTVolume:
    """The CT a scanner would record of the truth ``volume``: Gaussian PSF of ``psf_mm`` σ,
    trilinear resampling on the same grid moved by ``offset_vox`` voxels (i, j, k), white noise of
    ``noise_hu`` σ, rounded to int16 HU. The physical frame is the truth's (origin moved by the
    offset), so poses carry over unchanged."""
    sp = np.asarray(volume.spacing, float)
    data = gaussian_filter(np.asarray(volume.data, np.float32), psf_mm / sp[::-1], mode="nearest")
    off = np.asarray(offset_vox, float)
    nk, nj, ni = data.shape
    k, j, i = np.meshgrid(np.arange(nk) + off[2], np.arange(nj) + off[1], np.arange(ni) + off[0],
                          indexing="ij")
    res = map_coordinates(data, [k, j, i], order=1, mode="nearest")
    g = np.random.default_rng(_seed(seed, volume.name or "bone", "ct noise"))
    res = res + noise_hu * g.standard_normal(res.shape)
    origin = volume.index_to_physical(off[None])[0]
    return replace(volume, data=np.rint(res).astype(np.int16), origin=origin)


def layered_tissue(*, spacing: float = 3.0, fat_mm: float = 5.0, fat_hu: float = -90.0,
                   muscle_hu: float = 50.0, tendon_hu: float = 90.0, split_z_mm: float = 0.0,
                   blend_mm: float = 30.0, top_z_mm: float = 140.0) -> tuple[CTVolume, CTVolume]:
    """``(foot part, shank part)`` of a layered envelope (fat under the skin, muscle and tendon
    inside, the Achilles tendon behind the ankle), float32 HU; the parts split the attenuation as
    :func:`~core.synthetic.phantoms.soft_tissue_envelope` does."""
    spacing = positive(spacing, "spacing")
    shape, origin, pts = _envelope_grid(spacing, top_z_mm)
    d = S.sample_sdf(shape, pts)
    occ = _occupancy(d, spacing)
    inner = _occupancy(d + fat_mm, spacing)
    achilles = _occupancy(S.sample_sdf(S.RoundCone((-46, -2, -40), (-36, 0, 110), 4.0, 6.0), pts), spacing)
    hu = fat_hu + (muscle_hu - fat_hu) * inner + (tendon_hu - muscle_hu) * achilles * inner
    return _foot_and_shank(occ, hu - AIR_HU, pts, origin, spacing, split_z_mm, blend_mm)


@dataclass(frozen=True, eq=False)
class HardFootTrial:
    """The scene (renders the frames from the truth, neighbours included), the tracked bones'
    names and their CT volumes (:func:`ct_of`, what a tracker is given), and the truth's
    volumes of the tracked bones."""

    scene: object  # BiplaneScene
    names: tuple[str, ...]
    ct: tuple[CTVolume, ...]
    truth_volumes: tuple[CTVolume, ...]

    def truth(self, frame: int) -> np.ndarray:
        """``(n_tracked, 4, 4)`` true poses of the tracked bones (CT frame = anatomical frame)."""
        return self.scene.poses(frame)[: len(self.names)]


def make_hard_foot_scene(*, n_frames: int = 10, pixels: int = 512, seed: int = 0, spacing: float = 0.5,
                         tissue_spacing: float = 3.0, phase=(0.0, 0.6), jitter=(0.3, 0.3),
                         energy_kev: float = 60.0, aperture_radius: float | None = 1.0,
                         floor_thickness_mm: float = 5.0) -> HardFootTrial:
    """The harder trial (see the module docs): tibia, talus and calcaneus tracked; fibula and
    navicular rendered but untracked; layered soft tissue; the fluoroscope image chain of
    :meth:`~core.synthetic.ImagingModel.fluoroscope` on :func:`~core.synthetic.rig.foot_rig`;
    ``jitter`` (mm, degrees) of the seeded motion perturbation."""
    from .analytic import attenuation_per_mm
    from .imaging import ImagingModel
    from .motion import rotation_about, stance_trajectories
    from .rig import FLOOR_Z_MM, foot_rig
    from .scene import BiplaneScene

    ss = np.random.SeedSequence([int(seed), 0x4A7D]).spawn(3)
    g_rig, g_motion, g_img = (np.random.default_rng(s) for s in ss)
    rig = foot_rig(seed=g_rig, pixels=pixels)
    names = HARD_BONES + NEIGHBOURS
    ph = [hard_bone_phantom(n, spacing=spacing, seed=seed) for n in names]
    cents = {}
    for p in ph:
        m = p.volume.data > 200
        k, j, i = np.nonzero(m)
        cents[p.name] = p.volume.index_to_physical(np.column_stack([i, j, k]).mean(axis=0))
    traj3 = stance_trajectories(n_frames, names=HARD_BONES, seed=g_motion, phase=phase,
                                jitter_mm=float(jitter[0]), jitter_deg=float(jitter[1]),
                                centroids={n: cents[n] for n in HARD_BONES})
    s = np.linspace(phase[0], phase[1], int(n_frames))
    tn = rotation_about((40.0, 9.0, -20.0), (1.0, 0.0, 0.0), np.radians(3.0) * np.sin(np.pi * s))
    traj = np.concatenate([traj3, traj3[0][None], (traj3[1] @ tn)[None]])  # fibula, navicular
    models = tuple(ImagingModel.fluoroscope(c, rng=g_img, aperture_radius=aperture_radius) for c in rig)
    tissue = layered_tissue(spacing=tissue_spacing)
    floor = None
    if floor_thickness_mm > 0:
        floor = (FLOOR_Z_MM, float(floor_thickness_mm), attenuation_per_mm("carbon", energy_kev))
    scene = BiplaneScene(rig=rig, bones=tuple(p.volume for p in ph), trajectories=traj, imaging=models,
                         tissue=tissue, tissue_bones=(2, 0), floor=floor,
                         mu_water=attenuation_per_mm("water", energy_kev), seed=int(seed), names=names)
    ct = tuple(ct_of(p.volume, seed=seed) for p in ph[: len(HARD_BONES)])
    return HardFootTrial(scene, HARD_BONES, ct, tuple(p.volume for p in ph[: len(HARD_BONES)]))
