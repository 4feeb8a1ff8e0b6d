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

Bones that touch keep apart (:func:`keep_apart`): the perturbations move each bone on its own,
which can bring the tibia's plafond into the talar dome (seed 4's acceptance trial had them 1.86
mm into each other on the exact surfaces, the tracker's voxel-mask measure 2.07 mm). Where the joint
space on the phantoms' exact surfaces (:func:`joint_spaces`) falls below :data:`MIN_SPACE_MM`
anywhere in stance, the tibia (or the calcaneus) is translated off the talus along the contact
normal by the shortfall, smoothly in time (compact C² window of ±0.03 of stance); elsewhere the
poses are bit for bit those of the independent perturbations. Of make_foot_scene's seeds 0-9 this
changes 1, 3, 4, 6, 7 and 9 (seed 0, the acceptance trial, and 2, 5, 8 keep every pose); within the
acceptance study's 0.6 of stance (100 frames) the tibia moves by up to, in length, 1.94 mm for
seed 4 (frames 0-80; 1.82 mm of it up lab z), 0.77 mm for 9 (frames 50-99), 0.21 mm for 6 (37-99)
and, by the window's reach, 0.17 mm for 3 (91-99) and 0.09 mm for 7 (93-99).
A bone given its own centroid (another shape, e.g. the harder trial's) is left alone.
"""

from __future__ import annotations

import hashlib
from collections.abc import Mapping, Sequence

import numpy as np
from scipy.interpolate import CubicSpline

from . import sdf as S
from .phantoms import BONE_NAMES, FOOT_IN_LAB, SOLE_Z_MM, _extent, bone_centroid, bone_spec, voxel_grid

__all__ = ["CONTACTS", "LANDMARKS", "MIN_SPACE_MM", "joint_spaces", "keep_apart", "pose_about_centroid",
           "rotation_about", "stance_trajectories"]

#: Touching phantom bones, ``(moved, fixed)``: where their joint space falls below the minimum,
#: :func:`keep_apart` moves the first off the second (the tibia and the calcaneus off the talus).
CONTACTS = (("tibia", "talus"), ("calcaneus", "talus"))
#: Smallest joint space (mm, the phantoms' exact surfaces) :func:`stance_trajectories` keeps.
MIN_SPACE_MM = 0.05

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


def _fourier_draws(rng, n_dof, sigma, harmonics=3) -> list:
    """Amplitudes and phases of ``harmonics`` sine harmonics per degree of freedom (σ / k)."""
    out = []
    for k in range(1, harmonics + 1):
        amp = rng.normal(0.0, sigma / k, size=n_dof)
        ph = rng.uniform(0, 2 * np.pi, size=n_dof)
        out.append((amp, ph))
    return out


def _fourier(s, draws) -> np.ndarray:
    out = np.zeros((len(s), len(draws[0][0])))
    for k, (amp, ph) in enumerate(draws, start=1):
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
    min_space_mm: float | None = MIN_SPACE_MM,
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
    min_space_mm : float or None
        Smallest joint space kept between the phantoms' touching bones (:data:`CONTACTS`, both in
        ``names`` with their phantom shapes, i.e. no centroid of their own in ``centroids``) over
        the whole stance (:func:`keep_apart`); None: the bones move independently, as they did
        before (the same poses wherever the space never falls below ``min_space_mm``).

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

    bones = []  # (nominal chain link, centroid, rotation draws, translation draws) per bone
    for name in names:
        if name in _LINKS:
            c = cents.get(name, None)
            c = bone_centroid(name) if c is None else np.asarray(c, dtype=float)
            link = name
        elif name in cents:
            c, link = np.asarray(cents[name], dtype=float), "calcaneus"
        else:
            raise ValueError(f"names: {name!r} is not one of {BONE_NAMES}; give its centroid in "
                             "`centroids` to attach it to the foot")
        bones.append((link, c, _fourier_draws(rng, 3, np.radians(jitter_deg)),
                      _fourier_draws(rng, 3, jitter_mm)))

    def poses(s):
        nominal = _nominal_chain(s, place, keys, heel_strike_deg, heel_rise_deg)
        out = np.empty((len(bones), len(s), 4, 4))
        for b, (link, c, rv, tr) in enumerate(bones):
            out[b] = nominal[link] @ pose_about_centroid(_fourier(s, rv), _fourier(s, tr), c)
        return out

    out = poses(s)
    if min_space_mm is not None:
        pairs = [(a, b) for a, b in CONTACTS
                 if a in names and b in names and a not in cents and b not in cents]
        for a, c in keep_apart(poses, list(names), pairs, min_space_mm=float(min_space_mm)).items():
            out[list(names).index(a), :, :3, 3] += c(s)
    return out


#: Nominal chain link of each phantom bone (:func:`_nominal_chain`).
_LINKS = ("calcaneus", "talus", "tibia", "metatarsal2")


def _nominal_chain(s, place, keys, heel_strike_deg, heel_rise_deg) -> dict[str, np.ndarray]:
    """The chain's ``(len(s), 4, 4)`` poses per link at stance fractions ``s`` (module docs)."""
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
    return {"calcaneus": foot, "talus": talus, "tibia": tibia, "metatarsal2": meta}


# ---------------------------------------------------------------------------- joint spaces
#: Stance fractions at which :func:`keep_apart` measures the joint spaces, and the half-width of
#: its correction's time window (stance fractions).
_GRID = np.linspace(0.0, 1.0, 101)
_WINDOW = 0.03
_POINTS: dict[tuple[str, str], _Pair] = {}
_APART: dict[tuple, dict[str, np.ndarray]] = {}  # keep_apart's knots by the poses it was given


class _Pair:
    """Where the joint space of two touching phantoms is measured: points on the moved bone's
    surface within ``reach`` mm of the fixed bone, ~1 mm apart (``points``) and ~0.33 mm apart
    (``fine``, with a k-d tree), anatomical frame, mm; and the fixed bone's shape."""

    def __init__(self, moved: str, fixed: str, reach: float = 15.0) -> None:
        from scipy.spatial import cKDTree

        sa, sb = bone_spec(moved), bone_spec(fixed)
        self.shape = sb.shape
        lo_a, hi_a = _extent(sa.shape, sa.search, 0.0)
        lo_b, hi_b = _extent(sb.shape, sb.search, reach)
        lo, hi = np.maximum(lo_a, lo_b), np.minimum(hi_a, hi_b)
        p = _surface_points(sa.shape, lo, hi, 1.0)
        self.points = p[S.sample_sdf(sb.shape, p) < reach]
        q = _surface_points(sa.shape, lo, hi, 1.0 / 3.0)
        self.fine = q[S.sample_sdf(sb.shape, q) < reach]
        self.tree = cKDTree(self.fine)


def _surface_points(shape, lo, hi, spacing: float) -> np.ndarray:
    """Points ~``spacing`` apart on ``shape``'s surface in the box ``[lo, hi]`` (a grid three times
    coarser first, then its cells near the surface)."""
    _, pts, _ = voxel_grid(lo, hi, 3.0 * spacing)
    c = pts.reshape(-1, 3)
    c = c[np.abs(S.sample_sdf(shape, c)) < 3.0 * spacing]
    off = spacing * np.stack(np.meshgrid(*[np.arange(-1, 2)] * 3, indexing="ij"), axis=-1).reshape(-1, 3)
    p = np.unique(np.round((c[:, None] + off[None]).reshape(-1, 3) / spacing).astype(np.int64), axis=0)
    p = p * spacing
    p = p[np.abs(S.sample_sdf(shape, p)) < spacing / 2]
    for _ in range(3):  # onto the surface along the field's gradient
        p = p - shape(p)[:, None] * _unit_gradient(shape, p)
    return p


def _pair(moved: str, fixed: str) -> _Pair:
    if (moved, fixed) not in _POINTS:
        _POINTS[(moved, fixed)] = _Pair(moved, fixed)
    return _POINTS[(moved, fixed)]


def _unit_gradient(shape, p: np.ndarray, h: float = 1e-3) -> np.ndarray:
    g = np.stack([shape(p + h * e) - shape(p - h * e) for e in np.eye(3)], axis=1)
    return g / np.maximum(np.linalg.norm(g, axis=1, keepdims=True), 1e-12)


def _spaces(pair: _Pair, moved, fixed, lowest: int = 8, radius: float = 1.2) -> tuple[np.ndarray, np.ndarray]:
    """Per pose pair: the joint space (mm; the fixed bone's field at the moved bone's surface
    points, negative where they interpenetrate) and the unit normal (lab) along which moving the
    first bone opens it. The ``lowest`` of the 1 mm points are searched again among the 0.33 mm
    points within ``radius`` of them (an edge, such as the tibia's plafond rim, lies between them)."""
    M = np.linalg.solve(fixed, moved)  # T_fixed_from_moved
    q = np.einsum("nij,pj->npi", M[:, :3, :3], pair.points) + M[:, None, :3, 3]
    d = S.sample_sdf(pair.shape, q)
    low = np.argsort(d, axis=1)[:, :lowest]
    idx = [np.unique(np.concatenate(pair.tree.query_ball_point(pair.points[lo], radius))).astype(np.int64)
           for lo in low]
    fine = np.concatenate([pair.fine[i] @ M[f, :3, :3].T + M[f, :3, 3] for f, i in enumerate(idx)])
    e = S.sample_sdf(pair.shape, fine)
    cut = np.cumsum([0] + [len(i) for i in idx])
    best, near = np.empty(len(M)), np.empty((len(M), 3))
    for f in range(len(M)):
        j = cut[f] + int(np.argmin(e[cut[f]:cut[f + 1]]))
        best[f], near[f] = e[j], fine[j]
    n = np.einsum("nij,nj->ni", fixed[:, :3, :3], _unit_gradient(pair.shape, near))
    return best, n


def joint_spaces(poses: np.ndarray, names: Sequence[str], pairs=CONTACTS) -> dict[str, np.ndarray]:
    """Per pair of :data:`CONTACTS` present in ``names``: the smallest signed distance (mm) between
    the phantoms' exact surfaces at ``poses (n_bones, n_frames, 4, 4)``, per frame (negative: the
    bones interpenetrate)."""
    names = list(names)
    out = {}
    for a, b in pairs:
        if a in names and b in names:
            out[f"{a}-{b}"] = _spaces(_pair(a, b), poses[names.index(a)], poses[names.index(b)])[0]
    return out


def _blend(s, R: np.ndarray) -> np.ndarray:
    """``(len(s), 3)``: the knot vectors ``R`` (one per :data:`_GRID` fraction) averaged with
    compact C² weights ``(1 - (Δs / window)²)³``: zero (exactly) wherever no knot within the window
    is non-zero."""
    x = (np.asarray(s, float)[:, None] - _GRID[None, :]) / _WINDOW
    w = np.clip(1.0 - x * x, 0.0, None) ** 3
    return (w @ R) / w.sum(axis=1, keepdims=True)


def _dilate(r: np.ndarray) -> np.ndarray:
    """Each knot takes the largest of the vectors ``r`` within the window around it."""
    mag = np.linalg.norm(r, axis=1)
    out = np.zeros_like(r)
    for k, sk in enumerate(_GRID):
        near = np.flatnonzero(np.abs(_GRID - sk) <= _WINDOW + 1e-9)
        j = near[np.argmax(mag[near])]
        out[k] = r[j]
    return out


def keep_apart(poses, names: Sequence[str], pairs, *, min_space_mm: float = MIN_SPACE_MM,
               iterations: int = 12, tol: float = 0.002) -> dict:
    """Translations that keep touching phantom bones apart over the stance.

    ``poses(s)`` gives ``(n_bones, len(s), 4, 4)`` poses of ``names`` at stance fractions ``s``;
    ``pairs``: ``(moved, fixed)`` bones (:data:`CONTACTS`). The joint space is measured at 101
    fractions over the whole stance on the phantoms' exact surfaces (``fixed``'s signed distance
    field at points ~1 mm apart on ``moved``'s surface). Where it falls below ``min_space_mm`` the
    moved bone is translated along the contact normal by the shortfall — the window's largest
    shortfall (±0.03 of stance) at each fraction, averaged with compact C² weights over the window
    — and measured again until no fraction is short (by more than ``tol``). The translation is
    smooth in time and exactly zero more than two windows away from any short fraction, so
    frames there keep their poses bit for bit, and it does not depend on the frames sampled.

    Returns ``{moved: c}`` for the bones that need one, ``c(s) -> (len(s), 3)`` mm (lab) to add to
    their poses' translation. The knots are kept per process, keyed by the poses at the 101
    fractions (a trial's scene is often built more than once).
    """
    names = list(names)
    base = poses(_GRID)
    key = (hashlib.sha1(base.tobytes()).hexdigest(), tuple(names), tuple(map(tuple, pairs)),
           float(min_space_mm), int(iterations), float(tol))
    if key not in _APART:
        if len(_APART) > 64:
            _APART.clear()
        _APART[key] = _knots(base, names, pairs, min_space_mm, iterations, tol)
    return {a: (lambda s, R=R: _blend(s, R)) for a, R in _APART[key].items()}


def _knots(base, names, pairs, min_space_mm, iterations, tol) -> dict[str, np.ndarray]:
    out = {}
    for a, b in pairs:
        ia, ib = names.index(a), names.index(b)
        pair = _pair(a, b)
        R = np.zeros((len(_GRID), 3))
        c = np.zeros((len(_GRID), 3))
        d, n = _spaces(pair, base[ia], base[ib])
        for _ in range(int(iterations)):
            short = min_space_mm - d
            if short.max() <= tol:
                break
            R = R + _dilate(np.where(short > 0, short + tol, 0.0)[:, None] * n)
            new = _blend(_GRID, R)
            todo = np.flatnonzero(np.any(new != c, axis=1))  # measured again where it moved
            c = new
            moved = base[ia, todo].copy()
            moved[:, :3, 3] += c[todo]
            d[todo], n[todo] = _spaces(pair, moved, base[ib, todo])
        else:
            raise RuntimeError(f"keep_apart: {a}-{b} still {short.max():.3f} mm short after "
                               f"{iterations} corrections")
        if np.any(R):
            out[a] = R
    return out
