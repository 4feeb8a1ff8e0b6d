"""Joint kinematics of a trial: Grood–Suntay joint coordinate systems and helical axes per joint.

:mod:`core.tracking.kinematics` holds the per-pair maths (:func:`~core.tracking.kinematics.joint_angles`,
:func:`~core.tracking.kinematics.helical_axes`); this module names joints and computes what the
review plots, reports and exports show for them, in degrees and millimetres:

* :class:`Joint` — a proximal and a distal bone and the JCS axes: ``e1`` fixed in the proximal
  bone's anatomical frame (its ``e1_axis``), ``e3`` fixed in the distal one's (``e3_axis``), the
  floating axis ``e2 = e3 × e1``. The angles are the intrinsic Euler sequence (e1, e2, e3) of the
  distal anatomical frame relative to the proximal one (Grood & Suntay 1983; Wu et al. 2002 for
  the ankle: e1 = tibial medio-lateral axis, e3 = the distal bone's long axis).
* :func:`default_joints` — the joints of a set of bones: ankle (tibia–talus) and subtalar
  (talus–calcaneus) when those bones are there (the foot demo), else consecutive pairs.
* :func:`anatomical_frames` — ``T_bone_from_anatomical`` per bone: the principal axes of the
  bone's voxels (:func:`~core.tracking.kinematics.principal_axes_frame`) unless the user gives
  frames (landmarks through :func:`~core.tracking.kinematics.frame_from_axes`).
* :func:`joint_series` — per frame: JCS angles (deg), JCS translations (mm), and the helical
  axis of the relative motion from each frame to the next (angle, deg; translation along it, mm).
* :func:`compose_jcs` — the inverse: the distal frame relative to the proximal one from JCS
  angles and translations, built from elementary rotations (what the tests recover angles from).
* :func:`jcs_rms` — per joint and angle the RMS difference between two pose sets (e.g. tracked
  against reference poses).

Frames without a pose of either bone are NaN throughout.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from itertools import pairwise

import numpy as np

from .kinematics import helical_axes, joint_angles, principal_axes_frame

__all__ = ["Joint", "anatomical_frames", "compose_jcs", "default_joints", "jcs_rms", "joint_series",
           "volume_points"]

_AXES = ("x", "y", "z")


@dataclass(frozen=True)
class Joint:
    """A joint between ``proximal`` and ``distal`` bones (names) with its JCS axes."""

    name: str
    proximal: str
    distal: str
    e1_axis: str = "x"
    e3_axis: str = "z"

    def __post_init__(self) -> None:
        if self.e1_axis not in _AXES or self.e3_axis not in _AXES or self.e1_axis == self.e3_axis:
            raise ValueError(f"joint {self.name!r}: e1_axis, e3_axis: expected two different axes of "
                             f"'x', 'y', 'z', got {self.e1_axis!r}, {self.e3_axis!r}")
        if self.proximal == self.distal:
            raise ValueError(f"joint {self.name!r}: proximal and distal must be two bones, got "
                             f"{self.proximal!r} twice")

    @property
    def angle_names(self) -> tuple[str, str, str]:
        """Names of the three angles (about e1, the floating axis, e3)."""
        floating = ({"x", "y", "z"} - {self.e1_axis, self.e3_axis}).pop()
        return (f"about {self.proximal} {self.e1_axis} (e1)", f"floating {floating} (e2)",
                f"about {self.distal} {self.e3_axis} (e3)")


# Principal-axes frames put each bone's longest extent on z; e1 the proximal bone's x (its
# second-longest axis), e3 the distal bone's long axis z.
_FOOT = (Joint("ankle", "tibia", "talus"), Joint("subtalar", "talus", "calcaneus"))


def default_joints(bones: Sequence[str]) -> list[Joint]:
    """The joints to show for ``bones``: the ankle (tibia–talus) and subtalar (talus–calcaneus)
    joints when their bones are present, otherwise each consecutive pair of ``bones``."""
    have = set(bones)
    out = [j for j in _FOOT if j.proximal in have and j.distal in have]
    if out:
        return out
    return [Joint(f"{a}–{b}", a, b) for a, b in pairwise(bones)]


def volume_points(volume, threshold: float = 200.0, max_points: int = 20000) -> np.ndarray:
    """Voxel centres (the volume's physical frame, mm) of a CT (:class:`core.render.CTVolume`, HU)
    at or above ``threshold``, evenly thinned to at most ``max_points``: the points whose principal
    axes give a bone's default anatomical frame."""
    k, j, i = np.nonzero(np.asarray(volume.data) >= threshold)
    if len(i) < 4:
        raise ValueError(f"volume: fewer than 4 voxels of {getattr(volume, 'name', 'the bone')!r} reach "
                         f"{threshold} HU; expected a bone CT")
    step = max(1, len(i) // max_points)
    ijk = np.column_stack([i[::step], j[::step], k[::step]]).astype(float)
    return volume.index_to_physical(ijk)


def anatomical_frames(points: Mapping[str, np.ndarray], *,
                      given: Mapping[str, np.ndarray] | None = None) -> dict[str, np.ndarray]:
    """``T_bone_from_anatomical`` (4×4) per bone: ``given[bone]`` when the user set one (e.g.
    from landmarks with :func:`~core.tracking.kinematics.frame_from_axes`), else the principal
    axes of ``points[bone]`` ((n, 3) in the bone's frame, mm: mask voxel centres or vertices)."""
    given = dict(given or {})
    out = {}
    for bone, pts in points.items():
        if bone in given:
            T = np.asarray(given[bone], float)
            if T.shape != (4, 4) or not np.allclose(T[:3, :3].T @ T[:3, :3], np.eye(3), atol=1e-6):
                raise ValueError(f"given[{bone!r}]: expected a rigid 4x4 T_bone_from_anatomical")
            out[bone] = T
        else:
            out[bone] = principal_axes_frame(pts, long_axis="z")
    return out


def _check_series(poses: Mapping[str, np.ndarray], joint: Joint) -> tuple[np.ndarray, np.ndarray]:
    for b in (joint.proximal, joint.distal):
        if b not in poses:
            raise ValueError(f"poses: joint {joint.name!r} needs bone {b!r} (have {sorted(poses)})")
    P, D = (np.asarray(poses[b], float) for b in (joint.proximal, joint.distal))
    if P.shape != D.shape or P.ndim != 3 or P.shape[1:] != (4, 4):
        raise ValueError(f"poses: joint {joint.name!r}: expected two (n_frames, 4, 4) series of the same "
                         f"length, got {P.shape} and {D.shape}")
    return P, D


def joint_series(poses: Mapping[str, np.ndarray], joint: Joint,
                 frames: Mapping[str, np.ndarray] | None = None) -> dict[str, np.ndarray]:
    """JCS and helical-axis series of ``joint`` from ``poses`` (bone -> ``(n, 4, 4)``
    ``T_lab_from_bone``) and anatomical ``frames`` (bone -> ``T_bone_from_anatomical``; default
    identity).

    Returns ``angles_deg (n, 3)`` and ``translations_mm (n, 3)`` (about/along e1, e2, e3),
    ``helical_angle_deg (n,)`` and ``helical_translation_mm (n,)`` — the finite helical axis of
    the distal bone relative to the proximal one from frame ``i - 1`` to frame ``i`` (NaN at
    frame 0) — and ``sequence`` (the Euler sequence of the angles)."""
    P, D = _check_series(poses, joint)
    frames = frames or {}
    Fp = frames.get(joint.proximal)
    Fd = frames.get(joint.distal)
    jc = joint_angles(P, D, prox_frame=Fp, dist_frame=Fd, e1_axis=joint.e1_axis, e3_axis=joint.e3_axis)
    n = len(P)
    hel_a, hel_t = np.full(n, np.nan), np.full(n, np.nan)
    if n > 1:
        Ap = P @ (np.eye(4) if Fp is None else np.asarray(Fp, float))
        Ad = D @ (np.eye(4) if Fd is None else np.asarray(Fd, float))
        h = helical_axes(Ap, Ad)
        hel_a[1:] = np.rad2deg(h["angle"])
        hel_t[1:] = h["translation"]
    return {"angles_deg": np.rad2deg(jc["angles"]), "translations_mm": jc["translations"],
            "helical_angle_deg": hel_a, "helical_translation_mm": hel_t, "sequence": jc["sequence"]}


def _rot(axis: str, a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    i = _AXES.index(axis)
    j, k = (i + 1) % 3, (i + 2) % 3
    R = np.eye(3)
    R[j, j], R[j, k], R[k, j], R[k, k] = c, -s, s, c
    return R


def compose_jcs(angles_deg, translations_mm=(0.0, 0.0, 0.0), *, e1_axis: str = "x",
                e3_axis: str = "z") -> np.ndarray:
    """``T_prox_anat_from_dist_anat`` (4×4) with the given JCS angles (deg, about e1, the floating
    axis, e3) and translations (mm along e1, e2, e3): rotate about the proximal ``e1``, then about
    the floating axis (the once-rotated floating axis), then about the distal ``e3``; the origin
    displacement is ``t1 e1 + t2 e2 + t3 e3`` with e2 the floating axis ``e3 × e1`` (normalised)."""
    if e1_axis not in _AXES or e3_axis not in _AXES or e1_axis == e3_axis:
        raise ValueError(f"e1_axis, e3_axis: expected two different axes of 'x', 'y', 'z', got "
                         f"{e1_axis!r}, {e3_axis!r}")
    a1, a2, a3 = np.deg2rad(np.asarray(angles_deg, float))
    floating = ({"x", "y", "z"} - {e1_axis, e3_axis}).pop()
    R = _rot(e1_axis, a1) @ _rot(floating, a2) @ _rot(e3_axis, a3)
    e1 = np.eye(3)[:, _AXES.index(e1_axis)]
    e3 = R[:, _AXES.index(e3_axis)]
    e2 = np.cross(e3, e1)
    e2 /= np.linalg.norm(e2)
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = np.column_stack([e1, e2, e3]) @ np.asarray(translations_mm, float)
    return T


def jcs_rms(poses: Mapping[str, np.ndarray], reference: Mapping[str, np.ndarray], joints: Sequence[Joint],
            frames: Mapping[str, np.ndarray] | None = None) -> dict[str, dict]:
    """Per joint the RMS over frames (where both pose sets have both bones) of the difference of
    each JCS angle (deg) between ``poses`` and ``reference``, the RMS over all three angles, and
    the number of frames compared."""
    out = {}
    for j in joints:
        a = joint_series(poses, j, frames)["angles_deg"]
        b = joint_series(reference, j, frames)["angles_deg"]
        d = (a - b + 180.0) % 360.0 - 180.0
        ok = np.all(np.isfinite(d), axis=1)
        per = np.sqrt(np.mean(d[ok] ** 2, axis=0)) if ok.any() else np.full(3, np.nan)
        out[j.name] = {"rms_deg": [float(v) for v in per],
                       "rms_all_deg": float(np.sqrt(np.mean(d[ok] ** 2))) if ok.any() else float("nan"),
                       "frames": int(ok.sum())}
    return out
