"""Smooth, seeded stance-phase trajectories (heel strike → toe-off) of the foot bones.

Model
-----
A kinematic chain in the anatomical frame of :mod:`core.synthetic.phantoms`, placed in the lab by
``FOOT_IN_LAB`` and animated over the stance fraction ``s ∈ [0, 1]``:

* **Foot (calcaneus)** — rolls on the heel while the forefoot lowers (foot pitch ``-heel_strike_deg``
  → 0 over the first 15 % of stance), is flat in mid-stance, then rotates about the metatarsal
  heads as the heel rises (0 → ``heel_rise_deg`` over the second half): the rocker sequence of
  Perry's *Gait Analysis*.
* **Talus** — follows the calcaneus with a small rotation about the subtalar axis (42° up from
  the horizontal, 23° medial to the foot's long axis; Inman 1976): ~5° eversion during loading,
  ~6° inversion at push-off.
* **Tibia** — rotates about the talocrural axis through the centre of the talar dome: slight
  plantarflexion at loading, ~10° dorsiflexion in late stance, ~12° plantarflexion at toe-off
  (typical sagittal ankle curve), plus ~6° external rotation about its long axis; its centroid
  travels ~4–8 cm forward/up over stance.
* **Second metatarsal** — follows the foot with a few degrees of arch flattening in mid-stance.

Angle profiles are C²-smooth (quintic smoothstep ramps and a cubic spline through key angles),
so accelerations are bounded. On top, each bone gets a seeded perturbation about its *centroid*:
three Fourier harmonics per degree of freedom (defaults 1° and 1 mm, amplitude falling as 1/k).
Poses are ``T_lab_from_bone`` (4x4) mapping each phantom's physical (CT) frame into the lab.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
from scipy.interpolate import CubicSpline

from .phantoms import BONE_NAMES, FOOT_IN_LAB, SOLE_Z_MM, bone_centroid

__all__ = ["LANDMARKS", "pose_about_centroid", "rotation_about", "stance_trajectories"]

_sub = np.radians([42.0, 23.0])
#: Anatomical-frame pivots and axes (mm / unit vectors) used by the chain.
LANDMARKS = {
    "ankle_center": np.array([-3.0, 0.0, -31.0]),  # centre of curvature of the talar dome
    "ankle_axis": np.array([-0.1, 1.0, -0.14]) / np.linalg.norm([-0.1, 1.0, -0.14]),
    "subtalar_point": np.array([-10.0, 0.0, -32.0]),
    "subtalar_axis": np.array([np.cos(_sub[0]) * np.cos(_sub[1]),
                               np.cos(_sub[0]) * np.sin(_sub[1]), np.sin(_sub[0])]),
    "heel_contact": np.array([-40.0, -3.0, SOLE_Z_MM]),
    "mt_contact": np.array([136.0, 11.0, SOLE_Z_MM]),
    "midfoot_pivot": np.array([76.0, 8.0, -48.0]),
}


def rotation_about(point, axis, angle) -> np.ndarray:
    """``(..., 4, 4)`` rigid rotations by ``angle (...)`` rad about the line ``point`` + t ``axis``."""
    ang = np.asarray(angle, dtype=float)
    a = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    s, c = np.sin(ang)[..., None, None], np.cos(ang)[..., None, None]
    R = np.eye(3) + s * K + (1 - c) * (K @ K)
    T = np.zeros((*ang.shape, 4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = np.asarray(point, dtype=float) - R @ np.asarray(point, dtype=float)
    T[..., 3, 3] = 1.0
    return T


def _rotvec_matrix(rv: np.ndarray) -> np.ndarray:
    th = np.linalg.norm(rv, axis=-1)
    safe = np.where(th > 0, th, 1.0)
    a = rv / safe[..., None]
    K = np.zeros((*rv.shape[:-1], 3, 3))
    K[..., 0, 1], K[..., 0, 2], K[..., 1, 2] = -a[..., 2], a[..., 1], -a[..., 0]
    K = K - np.swapaxes(K, -1, -2)
    s, c = np.sin(th)[..., None, None], np.cos(th)[..., None, None]
    return np.eye(3) + s * K + (1 - c) * (K @ K)


def pose_about_centroid(rotvec, translation, centroid) -> np.ndarray:
    """``(..., 4, 4)`` transforms rotating by ``rotvec (..., 3)`` about ``centroid`` then
    translating by ``translation (..., 3)`` mm (all in the bone's own frame)."""
    R = _rotvec_matrix(np.asarray(rotvec, dtype=float))
    c = np.asarray(centroid, dtype=float)
    T = np.zeros((*R.shape[:-2], 4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = c - R @ c + np.asarray(translation, dtype=float)
    T[..., 3, 3] = 1.0
    return T


def _ramp(x):
    x = np.clip(x, 0.0, 1.0)
    return x**3 * (10 - 15 * x + 6 * x * x)  # quintic smoothstep: C2


def _fourier(s, rng, n_dof, sigma, harmonics=3):
    out = np.zeros((len(s), n_dof))
    for k in range(1, harmonics + 1):
        amp = rng.normal(0.0, sigma / k, size=n_dof)
        ph = rng.uniform(0, 2 * np.pi, size=n_dof)
        out += amp * np.sin(k * np.pi * s[:, None] + ph)
    return out


def stance_trajectories(
    n_frames: int,
    *,
    names: Sequence[str] = BONE_NAMES,
    seed: int | np.random.Generator = 0,
    phase=(0.0, 1.0),
    heel_strike_deg: float = 10.0,
    heel_rise_deg: float = 20.0,
    ankle_keys_deg=(0.0, -5.0, 5.0, 10.0, -12.0),
    jitter_deg: float = 1.0,
    jitter_mm: float = 1.0,
    placement=FOOT_IN_LAB,
    centroids: Mapping[str, np.ndarray] | None = None,
) -> np.ndarray:
    """Stance-phase ``T_lab_from_bone`` for each bone and frame.

    Parameters
    ----------
    n_frames : int
        Frames sampled evenly over ``phase``.
    names : sequence of str
        Bones (any of :data:`~core.synthetic.phantoms.BONE_NAMES`; another name follows the foot
        rigidly and needs its centroid in ``centroids``).
    seed : int or Generator
        Seed of the per-bone Fourier perturbations.
    phase : (float, float)
        Portion of stance covered, as fractions (0 = heel strike, 1 = toe-off).
    heel_strike_deg, heel_rise_deg : float
        Foot pitch (toes up) at heel strike and heel rise at toe-off, degrees.
    ankle_keys_deg : 5 floats
        Ankle dorsiflexion (+) at stance fractions 0, 0.12, 0.45, 0.75, 1 (cubic spline), degrees.
    jitter_deg, jitter_mm : float
        Size (σ of the first harmonic) of the seeded perturbation about each bone's centroid.
    placement : (4, 4) array
        ``T_lab_from_anatomical`` of the foot at heel strike.
    centroids : mapping, optional
        Bone centroids (anatomical frame, mm); default from the phantom shapes.

    Returns
    -------
    (n_bones, n_frames, 4, 4) float64 array
    """
    if int(n_frames) != n_frames or n_frames < 1:
        raise ValueError(f"n_frames: expected a positive integer, got {n_frames!r}")
    p0, p1 = (float(x) for x in phase)
    if not 0.0 <= p0 <= p1 <= 1.0:
        raise ValueError(f"phase: expected 0 <= start <= end <= 1, got {phase!r}")
    keys = np.radians(np.asarray(ankle_keys_deg, dtype=float))
    if keys.shape != (5,):
        raise ValueError(f"ankle_keys_deg: expected 5 angles, got {ankle_keys_deg!r}")
    place = np.asarray(placement, dtype=float)
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    cents = dict(centroids or {})
    s = np.linspace(p0, p1, int(n_frames))
    L = LANDMARKS

    def lab(p):
        return place[:3, :3] @ p + place[:3, 3]

    y_lab = place[:3, :3] @ np.array([0.0, 1.0, 0.0])
    th1 = -np.radians(heel_strike_deg) * (1 - _ramp(s / 0.15))
    th2 = np.radians(heel_rise_deg) * _ramp((s - 0.5) / 0.5)
    foot = (rotation_about(lab(L["mt_contact"]), y_lab, th2)
            @ rotation_about(lab(L["heel_contact"]), y_lab, th1) @ place)
    subtalar = np.radians(-5.0) * _ramp(s / 0.2) * (1 - _ramp((s - 0.3) / 0.4)) \
        + np.radians(6.0) * _ramp((s - 0.55) / 0.45)
    talus = foot @ rotation_about(L["subtalar_point"], L["subtalar_axis"], subtalar)
    ankle = CubicSpline([0.0, 0.12, 0.45, 0.75, 1.0], keys)(s)
    tib_rot = np.radians(-3.0 + 6.0 * _ramp(s))
    tibia = (talus @ rotation_about(L["ankle_center"], L["ankle_axis"], ankle)
             @ rotation_about(L["ankle_center"], [0, 0, 1], tib_rot))
    arch = np.radians(3.0) * np.sin(np.pi * s) ** 2
    meta = foot @ rotation_about(L["midfoot_pivot"], [0, 1, 0], -arch)
    nominal = {"calcaneus": foot, "talus": talus, "tibia": tibia, "metatarsal2": meta}

    out = np.empty((len(names), len(s), 4, 4))
    for b, name in enumerate(names):
        if name in nominal:
            c = cents.get(name, None)
            c = bone_centroid(name) if c is None else np.asarray(c, dtype=float)
            base = nominal[name]
        elif name in cents:
            c, base = np.asarray(cents[name], dtype=float), foot
        else:
            raise ValueError(f"names: {name!r} is not one of {BONE_NAMES}; give its centroid in "
                             "`centroids` to attach it to the foot")
        rv = _fourier(s, rng, 3, np.radians(jitter_deg))
        tr = _fourier(s, rng, 3, jitter_mm)
        out[b] = base @ pose_about_centroid(rv, tr, c)
    return out
