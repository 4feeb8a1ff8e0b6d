"""Rigid transforms, rotation parametrisations and the 6-parameter pose perturbation.

Conventions
-----------
* Lengths in mm, angles in **radians**.
* A rigid transform is a 4x4 matrix ``T = [[R, t], [0, 0, 0, 1]]`` acting on column vectors,
  ``x' = R x + t``; ``T_a_from_b`` maps coordinates of frame ``b`` into frame ``a``, so
  ``T_a_from_c = T_a_from_b @ T_b_from_c`` (:func:`compose_rigid`).
* Every function is vectorised over leading dimensions (``(..., 4, 4)``, ``(..., 3)``), which
  broadcast with numpy rules.
* Quaternions are **scalar-last** ``(x, y, z, w)`` by default (scipy's order); pass
  ``scalar_first=True`` for ``(w, x, y, z)``.
* Euler sequences follow scipy: three letters from ``xyz``; lower case = extrinsic (rotations
  about the fixed axes, applied left to right), upper case = intrinsic (about the moving axes).
  ``"xyz"`` (extrinsic) equals ``"ZYX"`` (intrinsic) with the angles reversed.
* Rotation vectors are axis * angle (radians), angle in ``[0, pi]``.

Pose parametrisation
--------------------
A bone pose is ``T_lab_from_bone``. Optimisers search a 6-vector
``p = (tx, ty, tz, rx, ry, rz)`` about a base pose and a centre ``c`` (bone coordinates, mm,
typically the bone's centroid)::

    c_lab = base @ c
    T(p)  = Translate(c_lab + t) @ Rot(r) @ Translate(-c_lab) @ base

so the rotation (rotation vector ``r``, axes of the **lab**) turns the bone about its centre, and
the translation ``t`` (lab, mm) is the displacement of the centre: ``T(p) @ c = c_lab + t``.
``p = 0`` gives ``base``.
"""

from __future__ import annotations

import warnings

import numpy as np
from scipy.spatial.transform import Rotation

from .._validate import as_float_array

__all__ = [
    "apply_rigid",
    "compose_rigid",
    "euler_to_matrix",
    "invert_rigid",
    "make_rigid",
    "matrix_to_euler",
    "matrix_to_quat",
    "matrix_to_rotvec",
    "params_from_pose",
    "pose_from_params",
    "quat_to_matrix",
    "random_perturbation",
    "rotvec_to_matrix",
]


# ---------------------------------------------------------------------------- validation
def _trailing(value, name: str, tail: tuple[int, ...]) -> np.ndarray:
    arr = as_float_array(value, name)
    if arr.ndim < len(tail) or arr.shape[arr.ndim - len(tail) :] != tail:
        want = "(..., " + ", ".join(map(str, tail)) + ")"
        raise ValueError(f"{name}: expected shape {want}, got {arr.shape}")
    return arr


def _rotations(value, name: str, *, atol: float = 1e-6) -> np.ndarray:
    R = _trailing(value, name, (3, 3))
    err = np.abs(R @ np.swapaxes(R, -1, -2) - np.eye(3)).max(initial=0.0)
    if err > atol:
        raise ValueError(
            f"{name}: expected orthonormal 3x3 rotation matrices, R @ R.T differs from the "
            f"identity by {err:.3g}"
        )
    if R.size and np.linalg.det(R).min() <= 0:
        raise ValueError(f"{name}: expected proper rotations (det = +1), found a reflection")
    return R


def _rigids(value, name: str, *, atol: float = 1e-6) -> np.ndarray:
    T = _trailing(value, name, (4, 4))
    if T.size and not np.allclose(T[..., 3, :], [0.0, 0.0, 0.0, 1.0], atol=1e-12):
        raise ValueError(f"{name}: expected last row (0, 0, 0, 1) in every 4x4 transform")
    _rotations(T[..., :3, :3], f"{name}[..., :3, :3]", atol=atol)
    return T


def _via_scipy(arr: np.ndarray, in_tail: tuple[int, ...], out_tail: tuple[int, ...], fn):
    """Apply ``fn`` to a flattened ``(N, *in_tail)`` stack and restore the leading shape."""
    lead = arr.shape[: arr.ndim - len(in_tail)]
    flat = arr.reshape(-1, *in_tail)
    if flat.shape[0] == 0:
        return np.zeros((*lead, *out_tail))
    return fn(flat).reshape(*lead, *out_tail)


# ---------------------------------------------------------------------------- 4x4 helpers
def make_rigid(R=None, t=None) -> np.ndarray:
    """4x4 rigid transform(s) from a rotation and a translation.

    Parameters
    ----------
    R : (..., 3, 3) array, optional
        Rotation(s); identity if omitted.
    t : (..., 3) array, optional
        Translation(s), mm; zero if omitted.

    Returns
    -------
    T : (..., 4, 4) array
        Leading dimensions of ``R`` and ``t`` broadcast.
    """
    R = np.eye(3) if R is None else _rotations(R, "R")
    t = np.zeros(3) if t is None else _trailing(t, "t", (3,))
    lead = np.broadcast_shapes(R.shape[:-2], t.shape[:-1])
    T = np.zeros((*lead, 4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = t
    T[..., 3, 3] = 1.0
    return T


def invert_rigid(T) -> np.ndarray:
    """Inverse of rigid transform(s) ``(..., 4, 4)``: ``[[R.T, -R.T t], [0, 1]]``."""
    T = _rigids(T, "T")
    R = T[..., :3, :3]
    Rt = np.swapaxes(R, -1, -2)
    out = np.zeros_like(T)
    out[..., :3, :3] = Rt
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", Rt, T[..., :3, 3])
    out[..., 3, 3] = 1.0
    return out


def compose_rigid(*transforms) -> np.ndarray:
    """Product ``T1 @ T2 @ ... @ Tn`` of rigid transforms (``Tn`` is applied first).

    Parameters
    ----------
    *transforms : (..., 4, 4) arrays
        At least one; leading dimensions broadcast.

    Returns
    -------
    T : (..., 4, 4) array
    """
    if not transforms:
        raise ValueError("transforms: expected at least one (..., 4, 4) rigid transform")
    out = _rigids(transforms[0], "transforms[0]")
    for i, T in enumerate(transforms[1:], start=1):
        out = out @ _rigids(T, f"transforms[{i}]")
    return out


def apply_rigid(T, X) -> np.ndarray:
    """Apply rigid transform(s) to points.

    Parameters
    ----------
    T : (..., 4, 4) array
        Rigid transform(s).
    X : (..., 3) array
        Points, mm. Leading dimensions broadcast with those of ``T`` (use ``T[:, None]`` for
        every transform applied to every point).

    Returns
    -------
    (..., 3) array
        ``R X + t``, mm.
    """
    T = _rigids(T, "T")
    X = _trailing(X, "X", (3,))
    return np.einsum("...ij,...j->...i", T[..., :3, :3], X) + T[..., :3, 3]


# ---------------------------------------------------------------------------- rotations
def rotvec_to_matrix(rotvec) -> np.ndarray:
    """Rotation matrices ``(..., 3, 3)`` from rotation vectors ``(..., 3)`` (axis * angle, rad)."""
    rv = _trailing(rotvec, "rotvec", (3,))
    return _via_scipy(rv, (3,), (3, 3), lambda a: Rotation.from_rotvec(a).as_matrix())


def matrix_to_rotvec(R) -> np.ndarray:
    """Rotation vectors ``(..., 3)`` (axis * angle, angle in [0, pi] rad) of ``(..., 3, 3)``."""
    R = _rotations(R, "R")
    return _via_scipy(R, (3, 3), (3,), lambda m: Rotation.from_matrix(m).as_rotvec())


def quat_to_matrix(q, *, scalar_first: bool = False) -> np.ndarray:
    """Rotation matrices from quaternions.

    Parameters
    ----------
    q : (..., 4) array
        Quaternions, ``(x, y, z, w)`` (scalar last) unless ``scalar_first``; normalised here,
        must be non-zero.
    scalar_first : bool
        ``q`` is ``(w, x, y, z)``.

    Returns
    -------
    R : (..., 3, 3) array
    """
    q = _trailing(q, "q", (4,))
    if q.size and np.linalg.norm(q, axis=-1).min() == 0:
        raise ValueError("q: expected non-zero quaternions, found one of norm 0")
    return _via_scipy(
        q, (4,), (3, 3), lambda a: Rotation.from_quat(a, scalar_first=scalar_first).as_matrix()
    )


def matrix_to_quat(R, *, scalar_first: bool = False) -> np.ndarray:
    """Unit quaternions ``(..., 4)`` of rotations ``(..., 3, 3)``.

    Scalar last ``(x, y, z, w)`` unless ``scalar_first``; the sign is chosen so that ``w >= 0``.
    """
    R = _rotations(R, "R")
    return _via_scipy(
        R,
        (3, 3),
        (4,),
        lambda m: Rotation.from_matrix(m).as_quat(canonical=True, scalar_first=scalar_first),
    )


def _check_seq(seq) -> str:
    if (
        not isinstance(seq, str)
        or len(seq) != 3
        or not (set(seq) <= set("xyz") or set(seq) <= set("XYZ"))
        or seq[0] == seq[1]
        or seq[1] == seq[2]
    ):
        raise ValueError(
            "seq: expected 3 axis letters, all lower case (extrinsic) or all upper case "
            f"(intrinsic), no axis twice in a row, e.g. 'xyz', 'ZYX', 'zxz'; got {seq!r}"
        )
    return seq


def euler_to_matrix(angles, seq: str) -> np.ndarray:
    """Rotation matrices ``(..., 3, 3)`` from Euler angles.

    Parameters
    ----------
    angles : (..., 3) array
        Angles in radians, in the order of ``seq``.
    seq : str
        Axis sequence: lower case = extrinsic (fixed axes), upper case = intrinsic (moving axes).
    """
    seq = _check_seq(seq)
    a = _trailing(angles, "angles", (3,))
    return _via_scipy(a, (3,), (3, 3), lambda x: Rotation.from_euler(seq, x).as_matrix())


def matrix_to_euler(R, seq: str) -> np.ndarray:
    """Euler angles ``(..., 3)`` (radians) of rotations ``(..., 3, 3)`` for axis sequence ``seq``.

    At gimbal lock the decomposition is not unique; the third angle is then set to 0 (scipy's
    choice) and the result still reproduces ``R`` exactly. scipy's gimbal-lock warning is
    passed through.
    """
    seq = _check_seq(seq)
    R = _rotations(R, "R")
    return _via_scipy(R, (3, 3), (3,), lambda m: Rotation.from_matrix(m).as_euler(seq))


# ---------------------------------------------------------------------------- pose parameters
def _base_and_centre(base, center):
    base = np.eye(4) if base is None else _rigids(base, "base")
    c = _trailing(center, "center", (3,))
    return base, c


def pose_from_params(params, *, center, base=None) -> np.ndarray:
    """Poses from 6-parameter perturbations about a centre (see the module docstring).

    Parameters
    ----------
    params : (..., 6) array
        ``(tx, ty, tz, rx, ry, rz)``: displacement of the centre in the lab (mm) and a rotation
        vector about lab axes through the centre (radians).
    center : (3,) array
        Rotation centre in bone coordinates, mm (e.g. the bone's centroid).
    base : (4, 4) or (..., 4, 4) array, optional
        Base pose ``T_lab_from_bone``; identity if omitted.

    Returns
    -------
    T : (..., 4, 4) array
        Perturbed poses ``T_lab_from_bone``; ``params = 0`` gives ``base``.
    """
    p = _trailing(params, "params", (6,))
    base, c = _base_and_centre(base, center)
    Rb, tb = base[..., :3, :3], base[..., :3, 3]
    c_lab = np.einsum("...ij,...j->...i", Rb, c) + tb
    Rd = rotvec_to_matrix(p[..., 3:])
    R = Rd @ Rb
    t = c_lab + p[..., :3] - np.einsum("...ij,...j->...i", R, c)
    return make_rigid(R, t)


def params_from_pose(T, *, center, base=None) -> np.ndarray:
    """Inverse of :func:`pose_from_params`.

    Parameters
    ----------
    T : (..., 4, 4) array
        Poses ``T_lab_from_bone``.
    center : (3,) array
        Rotation centre in bone coordinates, mm.
    base : (4, 4) or (..., 4, 4) array, optional
        Base pose; identity if omitted.

    Returns
    -------
    params : (..., 6) array
        ``(tx, ty, tz, rx, ry, rz)`` in mm and radians (rotation angle in ``[0, pi]``).
    """
    T = _rigids(T, "T")
    base, c = _base_and_centre(base, center)
    Rd = T[..., :3, :3] @ np.swapaxes(base[..., :3, :3], -1, -2)
    rv = matrix_to_rotvec(Rd)
    disp = (
        np.einsum("...ij,...j->...i", T[..., :3, :3], c)
        + T[..., :3, 3]
        - np.einsum("...ij,...j->...i", base[..., :3, :3], c)
        - base[..., :3, 3]
    )
    lead = np.broadcast_shapes(rv.shape[:-1], disp.shape[:-1])
    return np.concatenate(
        [np.broadcast_to(disp, (*lead, 3)), np.broadcast_to(rv, (*lead, 3))], axis=-1
    )


def _unit_vectors(rng: np.random.Generator, n: int) -> np.ndarray:
    v = rng.standard_normal((n, 3))
    norm = np.linalg.norm(v, axis=1, keepdims=True)
    norm[norm == 0] = 1.0
    return v / norm


def random_perturbation(
    rng, n: int, *, trans_mm: float, rot_rad: float, distribution: str = "ball"
) -> np.ndarray:
    """Random 6-parameter perturbations for :func:`pose_from_params`.

    Directions (of the translation and of the rotation axis) are uniform on the sphere.

    Parameters
    ----------
    rng : numpy.random.Generator or int or None
        Random generator (or a seed for :func:`numpy.random.default_rng`).
    n : int
        Number of perturbations.
    trans_mm : float
        Translation magnitude bound, mm (>= 0).
    rot_rad : float
        Rotation angle bound, radians, in ``[0, pi]``.
    distribution : {"ball", "sphere"}
        ``"ball"``: translation and rotation vectors uniform in the balls of radii ``trans_mm``
        and ``rot_rad``; ``"sphere"``: magnitudes exactly ``trans_mm`` and ``rot_rad`` (for
        capture-range studies at a fixed offset).

    Returns
    -------
    params : (n, 6) array
        ``(tx, ty, tz, rx, ry, rz)``, mm and radians.
    """
    if isinstance(n, bool) or int(n) != n or n < 0:
        raise ValueError(f"n: expected a non-negative integer, got {n!r}")
    n = int(n)
    trans_mm, rot_rad = float(trans_mm), float(rot_rad)
    if not np.isfinite(trans_mm) or trans_mm < 0:
        raise ValueError(f"trans_mm: expected a finite number >= 0 (mm), got {trans_mm}")
    if not np.isfinite(rot_rad) or not 0 <= rot_rad <= np.pi:
        raise ValueError(f"rot_rad: expected an angle in [0, pi] radians, got {rot_rad}")
    if distribution not in ("ball", "sphere"):
        raise ValueError(f'distribution: expected "ball" or "sphere", got {distribution!r}')
    gen = np.random.default_rng(rng)
    dt, dr = _unit_vectors(gen, n), _unit_vectors(gen, n)
    if distribution == "ball":
        mt = trans_mm * np.cbrt(gen.random(n))[:, None]
        mr = rot_rad * np.cbrt(gen.random(n))[:, None]
    else:
        mt, mr = trans_mm, rot_rad
    return np.hstack([dt * mt, dr * mr])


def _quiet_euler(R: np.ndarray, seq: str) -> np.ndarray:
    """``as_euler`` without scipy's gimbal-lock warning (the result is exact either way)."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Gimbal lock", category=UserWarning)
        return Rotation.from_matrix(R).as_euler(seq)
