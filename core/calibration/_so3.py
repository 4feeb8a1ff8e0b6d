"""Vectorised rotation-vector helpers for the bundle adjustment (private)."""

from __future__ import annotations

import numpy as np


def hat(w: np.ndarray) -> np.ndarray:
    """``(..., 3)`` -> ``(..., 3, 3)`` cross-product matrices ``[w]ₓ``."""
    z = np.zeros(w.shape[:-1])
    return np.stack([
        np.stack([z, -w[..., 2], w[..., 1]], -1),
        np.stack([w[..., 2], z, -w[..., 0]], -1),
        np.stack([-w[..., 1], w[..., 0], z], -1),
    ], -2)


def _coeffs(w: np.ndarray):
    th2 = np.sum(w * w, axis=-1)
    th = np.sqrt(th2)
    small = th < 1e-4
    ths = np.where(small, 1.0, th)
    a = np.where(small, 1 - th2 / 6, np.sin(ths) / ths)
    b = np.where(small, 0.5 - th2 / 24, (1 - np.cos(ths)) / ths**2)
    c = np.where(small, 1 / 6 - th2 / 120, (ths - np.sin(ths)) / ths**3)
    return a, b, c


def exp(w: np.ndarray) -> np.ndarray:
    """Rodrigues: rotation vectors ``(..., 3)`` -> rotation matrices ``(..., 3, 3)``."""
    a, b, _ = _coeffs(w)
    K = hat(w)
    return np.eye(3) + a[..., None, None] * K + b[..., None, None] * (K @ K)


def left_jacobian(w: np.ndarray) -> np.ndarray:
    """``J_l(w)`` with ``exp(w + δ) ≈ exp(J_l δ) exp(w)``; ``(..., 3)`` -> ``(..., 3, 3)``."""
    _, b, c = _coeffs(w)
    K = hat(w)
    return np.eye(3) + b[..., None, None] * K + c[..., None, None] * (K @ K)


def log(R: np.ndarray) -> np.ndarray:
    """Rotation matrices ``(..., 3, 3)`` -> rotation vectors (angle in [0, π])."""
    from scipy.spatial.transform import Rotation

    R = np.asarray(R, dtype=float)
    return Rotation.from_matrix(R.reshape(-1, 3, 3)).as_rotvec().reshape(*R.shape[:-2], 3)


def mean_rotation(Rs: np.ndarray) -> np.ndarray:
    """Chordal L2 mean of ``(n, 3, 3)`` rotations (projection of their sum onto SO(3))."""
    U, _, Vt = np.linalg.svd(np.sum(Rs, axis=0))
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


def rigid(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    T = np.zeros((*R.shape[:-2], 4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = t
    T[..., 3, 3] = 1.0
    return T


def inv(T: np.ndarray) -> np.ndarray:
    R = np.swapaxes(T[..., :3, :3], -1, -2)
    return rigid(R, -np.einsum("...ij,...j->...i", R, T[..., :3, 3]))
