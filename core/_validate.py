"""Argument validation shared by :mod:`core`; every error names the argument and the expectation."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np


def as_float_array(
    value,
    name: str,
    *,
    shape: Sequence[int | None] | None = None,
    ndim: int | None = None,
    finite: bool = True,
    dtype=np.float64,
) -> np.ndarray:
    """Convert ``value`` to a float array and check its shape and finiteness.

    ``shape`` may contain ``None`` for a free axis; a leading ``...`` is not supported, use
    ``ndim`` instead. Raises ``ValueError`` naming ``name``.
    """
    try:
        arr = np.asarray(value, dtype=dtype)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name}: expected a numeric array, got {type(value).__name__}") from exc
    if ndim is not None and arr.ndim != ndim:
        raise ValueError(f"{name}: expected a {ndim}-D array, got shape {arr.shape}")
    if shape is not None:
        ok = arr.ndim == len(shape) and all(
            s is None or s == a for s, a in zip(shape, arr.shape, strict=False)
        )
        if not ok:
            dims = ["N" if s is None else str(s) for s in shape]
            want = f"({dims[0]},)" if len(dims) == 1 else "(" + ", ".join(dims) + ")"
            raise ValueError(f"{name}: expected shape {want}, got {arr.shape}")
    if finite and not np.all(np.isfinite(arr)):
        raise ValueError(f"{name}: contains NaN or infinite values")
    return arr


def as_points(value, name: str, dim: int) -> tuple[np.ndarray, tuple[int, ...]]:
    """Return ``(points (N, dim), leading_shape)`` for an array of shape ``(..., dim)``."""
    arr = as_float_array(value, name)
    if arr.ndim == 0 or arr.shape[-1] != dim:
        raise ValueError(f"{name}: expected shape (..., {dim}), got {arr.shape}")
    lead = arr.shape[:-1]
    return arr.reshape(-1, dim), lead


def positive(value: float, name: str) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name}: expected a positive number, got {value!r}") from exc
    if not np.isfinite(v) or v <= 0:
        raise ValueError(f"{name}: expected a positive finite number, got {value!r}")
    return v


def check_rotation(R, name: str = "R", *, atol: float = 1e-6) -> np.ndarray:
    """A 3x3 proper rotation matrix (orthonormal, det = +1 within ``atol``)."""
    R = as_float_array(R, name, shape=(3, 3))
    if not np.allclose(R @ R.T, np.eye(3), atol=atol):
        err = np.abs(R @ R.T - np.eye(3)).max()
        raise ValueError(
            f"{name}: expected an orthonormal 3x3 rotation matrix, R @ R.T differs from the "
            f"identity by {err:.3g}"
        )
    if np.linalg.det(R) <= 0:
        raise ValueError(f"{name}: expected a proper rotation (det = +1), got det {np.linalg.det(R):.3g}")
    return R


def check_rigid(T, name: str = "T", *, atol: float = 1e-6) -> np.ndarray:
    """A 4x4 rigid transform: rotation block, translation column, last row (0, 0, 0, 1)."""
    T = as_float_array(T, name, shape=(4, 4))
    check_rotation(T[:3, :3], f"{name}[:3, :3]", atol=atol)
    if not np.allclose(T[3], [0, 0, 0, 1], atol=1e-12):
        raise ValueError(f"{name}: expected last row (0, 0, 0, 1), got {T[3]}")
    return T
