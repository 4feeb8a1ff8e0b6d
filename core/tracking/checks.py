"""The tracker's checks of a registration: failure reasons, same optimum, uncertainty.

:func:`failures` lists why a registration of :func:`core.tracking.trial.track` fails (not
converged, a score drop against the bone's recent good frames or below its first frame, a jump
from the initial guess); :func:`same_optimum` tells whether two poses are the same optimum
(:data:`SAME_OPTIMUM`); :func:`uncertain` flags a confidence beyond the user's limits. See the
module docs of :mod:`core.tracking.trial` for how the tracker uses them.

Pose differences are taken in closed form (:func:`pose_delta`, :func:`step_pose`): the same
values as :func:`core.geometry.transforms.params_from_pose` and
:func:`~core.geometry.transforms.pose_from_params` (to rounding), without their input checks
and scipy's rotation objects — the tracker's own rigid poses, a few per frame.
"""

from __future__ import annotations

import numpy as np

from ..geometry.transforms import params_from_pose, pose_from_params

__all__ = ["SAME_OPTIMUM", "failures", "pose_delta", "same_optimum", "step_pose", "uncertain"]

#: Poses closer than this (mm, degrees) are the same optimum (:func:`same_optimum`).
SAME_OPTIMUM = (0.5, 0.5)


def _rotvec(R: np.ndarray) -> np.ndarray | None:
    """Rotation vector (rad) of a rotation matrix, or None near a half turn (left to scipy)."""
    w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    s = 0.5 * float(np.linalg.norm(w))  # sin(angle)
    c = 0.5 * (float(np.trace(R)) - 1.0)  # cos(angle)
    th = float(np.arctan2(s, c))
    if th > 3.0:  # near pi the antisymmetric part loses the axis
        return None
    k = 0.5 if s < 1e-12 else th / (2.0 * s)
    return k * w


def pose_delta(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Parameters (mm, rad) taking rigid pose ``a`` to pose ``b`` about centre ``c`` (bone frame):
    :func:`~core.geometry.transforms.params_from_pose` ``(b, center=c, base=a)``."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    c = np.asarray(c, dtype=float)
    Ra, Rb = a[:3, :3], b[:3, :3]
    rv = _rotvec(Rb @ Ra.T)
    if rv is None or not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
        return params_from_pose(b, center=c, base=a)
    disp = Rb @ c + b[:3, 3] - Ra @ c - a[:3, 3]
    return np.r_[disp, rv]


def step_pose(p: np.ndarray, base: np.ndarray, c: np.ndarray) -> np.ndarray:
    """:func:`~core.geometry.transforms.pose_from_params` ``(p, center=c, base=base)`` of one
    parameter vector ``p`` (mm, rad) about a rigid ``base``."""
    p = np.asarray(p, dtype=float)
    base = np.asarray(base, dtype=float)
    c = np.asarray(c, dtype=float)
    if not (np.all(np.isfinite(p)) and np.all(np.isfinite(base))):
        return pose_from_params(p, center=c, base=base)
    r = p[3:]
    th = float(np.linalg.norm(r))
    Rd = np.eye(3)
    if th > 0:
        k = r / th
        K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
        Rd = Rd + np.sin(th) * K + (1.0 - np.cos(th)) * (K @ K)
    Rb, tb = base[:3, :3], base[:3, 3]
    R = Rd @ Rb
    out = np.eye(4)
    out[:3, :3] = R
    out[:3, 3] = Rb @ c + tb + p[:3] - R @ c
    return out


def _distance(a, b, c) -> tuple[float, float]:
    d = pose_delta(a, b, c)
    return float(np.linalg.norm(d[:3])), float(np.degrees(np.linalg.norm(d[3:])))


def failures(res, guess_pose, center, good_scores, o, *, start_score=None,
             jump_factor: float = 1.0) -> list[str]:
    """Why registration ``res`` fails under the tracking options ``o`` (module docs of
    :mod:`core.tracking.trial`): ``good_scores`` are the bone's good scores so far,
    ``start_score`` its first frame's; the jump limit is ``o.max_jump`` × ``jump_factor``."""
    out = []
    if not res.converged:
        out.append(f"not converged ({res.reason})")
    if good_scores:
        recent = good_scores[-o.history:]
        med = float(np.median(recent))
        if res.score < o.min_score_ratio * med:
            out.append(f"score drop ({res.score:.3f} < {o.min_score_ratio:g} x recent median {med:.3f})")
    if start_score is not None and res.score < o.min_start_ratio * start_score:
        out.append(f"score below the start ({res.score:.3f} < {o.min_start_ratio:g} x first frame "
                   f"{start_score:.3f})")
    dt, dr = _distance(guess_pose, res.pose, center)
    if dt > o.max_jump[0] * jump_factor or dr > o.max_jump[1] * jump_factor:
        out.append(f"pose jump ({dt:.2f} mm, {dr:.2f} deg from the guess)")
    return out


def same_optimum(a: np.ndarray, b: np.ndarray, center) -> bool:
    """Whether poses ``a`` and ``b`` are within :data:`SAME_OPTIMUM` of each other."""
    dt, dr = _distance(a, b, center)
    return bool(dt <= SAME_OPTIMUM[0] and dr <= SAME_OPTIMUM[1])


def uncertain(conf: dict | None, limits: tuple[float, float]) -> list[str]:
    """The ``"uncertain"`` flag of a frame's confidence (a dict of
    :class:`~core.tracking.confidence.PoseConfidence`) beyond ``limits`` (mm, degrees)."""
    lt, lr = (float(v) for v in limits)
    if conf is None:
        return ["uncertain (no confidence could be computed)"]
    t, r = conf.get("translation_mm"), conf.get("rotation_deg")
    if not conf.get("well_posed", True) or t is None or r is None:
        return ["uncertain (the pose is not determined along every axis)"]
    if t > lt or r > lr:
        return [f"uncertain (confidence {t:.3f} mm, {r:.3f} deg; limits {lt:g} mm, {lr:g} deg)"]
    return []
