"""Bones that touch: signed surface distance between bones, and a non-interpenetration constraint.

A :class:`ContactModel` holds a bone's signed distance field (mm; negative inside the bone,
positive outside) on its CT grid, computed from the bone mask with holes filled (trabecular
marrow below the threshold is still bone) by two Euclidean distance transforms, and a few
hundred points on the mask's surface. The distance of bone A's surface to bone B at poses
``(T_A, T_B)`` is B's field at A's surface points mapped into B's CT frame
(``T_B⁻¹ T_A p``), trilinearly interpolated; :func:`surface_gap` is the smallest of both ways
round (the joint space; negative = the bones interpenetrate). It agrees with the mesh distance of
:func:`core.tracking.kinematics.min_distance` to within about half a voxel and needs no mesh.

Joint tracking (:mod:`core.tracking.trial`, ``TrackingOptions.contact``) adds
:func:`penetration_penalty` — ``weight`` × the mean square depth (mm²) by which the deepest 5 %
of the bone's surface points come closer than ``margin`` mm to a neighbour — to the image cost of
a registration whose result comes closer than the margin to a neighbour at its current estimate,
and polishes the pose under it (:func:`polish_with_contact`): overlapping bones cannot trade
image evidence by passing through each other. With ``weight`` = 0.05 / mm² one millimetre of
interpenetration costs 0.05, several times the cost change of a millimetre of image
misregistration near the optimum (gradient correlation cost, ~0.002–0.01 / mm²).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

__all__ = ["ContactModel", "penetration_depths", "penetration_penalty", "polish_with_contact",
           "surface_gap"]


@dataclass(frozen=True, eq=False)
class ContactModel:
    """A bone's signed distance field (``sdf`` on the CT grid ``[k, j, i]``, mm) with the grid's
    ``origin``, ``spacing`` and ``direction``, and ``points (n, 3)`` on its surface (CT frame, mm)."""

    name: str
    sdf: np.ndarray
    origin: np.ndarray
    spacing: np.ndarray
    direction: np.ndarray
    points: np.ndarray

    @classmethod
    def from_bone(cls, model, *, max_points: int = 800, close_iterations: int = 2) -> ContactModel:
        """From a :class:`core.tracking.bones.BoneModel` (its mask, holes filled)."""
        from scipy.ndimage import binary_closing, binary_erosion, binary_fill_holes, distance_transform_edt

        m = np.asarray(model.mask, bool)
        pad = close_iterations + 1
        mp = np.pad(m, pad)
        if close_iterations > 0:
            mp = binary_closing(mp, iterations=int(close_iterations))
        mp = binary_fill_holes(mp)[pad:-pad, pad:-pad, pad:-pad]
        vol = model.volume
        sp = np.asarray(vol.spacing, float)
        samp = sp[::-1]
        d_out = distance_transform_edt(~mp, sampling=samp)
        d_in = distance_transform_edt(mp, sampling=samp)
        sdf = (np.where(mp, -(d_in - 0.5 * samp.min()), d_out - 0.5 * samp.min())).astype(np.float32)
        shell = mp & ~binary_erosion(mp)
        k, j, i = np.nonzero(shell)
        P = vol.index_to_physical(np.column_stack([i, j, k]).astype(float))
        if len(P) > max_points:
            P = P[np.random.default_rng(0).choice(len(P), max_points, replace=False)]
        return cls(model.name, sdf, np.asarray(vol.origin, float), sp, np.asarray(vol.direction, float), P)

    def signed_distance(self, points) -> np.ndarray:
        """Signed distance (mm) of CT-frame ``points (..., 3)`` to the bone's surface; outside the
        grid, the distance at the nearest grid point plus the distance to the grid."""
        from scipy.ndimage import map_coordinates

        p = np.asarray(points, float)
        flat = p.reshape(-1, 3)
        ijk = ((flat - self.origin) @ self.direction) / self.spacing  # direction columns = axes
        n = np.array(self.sdf.shape[::-1], float)
        c = np.clip(ijk, 0, n - 1)
        beyond = np.linalg.norm((ijk - c) * self.spacing, axis=1)
        d = map_coordinates(self.sdf, [c[:, 2], c[:, 1], c[:, 0]], order=1, mode="nearest")
        return (d + beyond).reshape(p.shape[:-1])


def _in_frame(a: ContactModel, Pa: np.ndarray, Pb: np.ndarray) -> np.ndarray:
    """A's surface points at pose(s) ``Pa (..., 4, 4)`` in B's CT frame at pose ``Pb (4, 4)``."""
    M = np.linalg.inv(np.asarray(Pb, float)) @ np.asarray(Pa, float)
    return a.points @ np.swapaxes(M[..., :3, :3], -1, -2) + M[..., None, :3, 3]


def surface_gap(a: ContactModel, Pa, b: ContactModel, Pb) -> float:
    """Smallest signed distance (mm) between the surfaces of A at ``Pa`` and B at ``Pb`` (4x4
    ``T_lab_from_bone`` each): the joint space, negative when they interpenetrate."""
    d1 = b.signed_distance(_in_frame(a, Pa, Pb)).min()
    d2 = a.signed_distance(_in_frame(b, Pb, Pa)).min()
    return float(min(d1, d2))


def penetration_depths(a: ContactModel, Pa, others: Sequence[tuple[ContactModel, np.ndarray]], *,
                       margin: float = 0.0, fraction: float = 0.05) -> np.ndarray:
    """``(B,)`` RMS depth (mm) by which the deepest ``fraction`` of A's surface points (at each of
    the poses ``Pa (B, 4, 4)``) come closer than ``margin`` mm to any of ``others`` (contact
    model, pose), both ways round; 0 where none does."""
    Pa = np.asarray(Pa, float).reshape(-1, 4, 4)
    k_a = max(1, round(fraction * len(a.points)))
    tot = np.zeros(len(Pa))
    for b, Pb in others:
        Pb = np.asarray(Pb, float)
        d = b.signed_distance(_in_frame(a, Pa, Pb))  # (B, n_a)
        pen = np.maximum(margin - d, 0.0)
        tot += np.mean(np.sort(pen, axis=1)[:, -k_a:] ** 2, axis=1)
        # B's points inside A (A's poses vary): B's points in A's frame at each pose
        M = np.linalg.inv(Pa) @ Pb
        q = b.points @ np.swapaxes(M[:, :3, :3], -1, -2) + M[:, None, :3, 3]
        pen = np.maximum(margin - a.signed_distance(q), 0.0)
        k_b = max(1, round(fraction * len(b.points)))
        tot += np.mean(np.sort(pen, axis=1)[:, -k_b:] ** 2, axis=1)
    return np.sqrt(tot)


def penetration_penalty(a: ContactModel, Pa, others, *, weight: float = 0.05,
                        margin: float = 0.0) -> np.ndarray:
    """``weight × penetration_depths² `` (cost units; see the module docs)."""
    return weight * penetration_depths(a, Pa, others, margin=margin) ** 2


def polish_with_contact(renderer, frame, *, bone: int, pose, center, contact: ContactModel,
                        neighbours: Sequence[tuple[ContactModel, np.ndarray]], terms, others=None,
                        outline=None, weight: float = 0.05, margin: float = 0.0, step=(0.25, 0.5),
                        bounds=(2.0, 2.0), margin_px: int = 4, cancel=None):
    """Minimise the image cost plus :func:`penetration_penalty` about ``pose`` (a quadratic-model
    search in a box of ``bounds`` mm / degrees). Returns ``(pose, score, fit, evaluations,
    depth_mm)``: the polished pose, its image similarity, the last quadratic fit (of the
    penalised cost: its curvature holds the constraint) and the remaining penetration depth."""
    import math

    from .cost import RegistrationCost, search_roi
    from .quadratic import quadratic_search

    views = tuple(range(frame.n_views))
    roi = search_roi(renderer, pose, bone, views=views, center=center,
                     reach_mm=bounds[0] + math.radians(bounds[1]) * 30.0, margin_px=margin_px, points=outline)
    cost = RegistrationCost(renderer, frame, bone=bone, base_pose=pose, center=center, roi=roi, terms=terms,
                            others=others)

    def fun(X):
        X = np.atleast_2d(X)
        return cost(X) + penetration_penalty(contact, cost.poses(X), neighbours, weight=weight, margin=margin)

    hi = np.array([bounds[0]] * 3 + [bounds[1]] * 3, float)
    h = np.array([step[0]] * 3 + [step[1]] * 3, float)
    r = quadratic_search(fun, np.zeros(6), step=2 * h, min_step=h, lower=-hi, upper=hi, tol_x=0.02,
                         max_generations=8, cancel=cancel)
    P = cost.poses(r.x[None])[0]
    depth = float(penetration_depths(contact, P[None], neighbours, margin=margin)[0])
    return P, cost.score(r.x), r.model, r.evaluations, depth
