"""The likelihood final stage's host pieces (:mod:`core.tracking.final_stage` re-exports them): the
robust factors' host reference (:func:`robust_factors`; the stage filters them on the device,
:func:`core.tracking.likelihood_kernels.robust_factors_device`), the bone's support mask
(``FinalModel.support_px``) and the stage pose's parameters (:func:`stage_params`)."""

from __future__ import annotations

import numpy as np

__all__ = ["robust_factors", "stage_params"]


def robust_factors(e: np.ndarray, used: np.ndarray, k: float, *, sigma_px: float = 2.0,
                   kind: str = "cauchy") -> np.ndarray:
    """Per pixel of ``e (views, H, W)`` (the weighted residual; ``used`` its usable pixels) the
    factor of its weight (:mod:`core.tracking.final_stage`'s docs): 1 where the local residual RMS
    is that of the view's typical pixel, falling where it is ``k`` times larger or more; 0 where not
    ``used``."""
    from scipy import ndimage

    e = np.asarray(e, dtype=np.float64)
    used = np.asarray(used, dtype=bool)
    out = np.zeros(e.shape, np.float64)
    for v in range(e.shape[0]):
        m = used[v]
        if not m.any():
            continue
        num = ndimage.gaussian_filter(np.where(m, e[v] ** 2, 0.0), sigma_px, mode="constant")
        den = ndimage.gaussian_filter(m.astype(np.float64), sigma_px, mode="constant")
        local = np.sqrt(num / np.maximum(den, 1e-6))
        s = float(np.median(local[m]))
        if not (np.isfinite(s) and s > 0):
            out[v] = m
            continue
        u = local / s
        f = 1.0 / (1.0 + (u / k) ** 2) if kind == "cauchy" else np.minimum(1.0, k / np.maximum(u, 1e-12))
        out[v] = np.where(m, f, 0.0)
    return out


def _support_mask(eng, px: float) -> np.ndarray:
    """The bone's DRR support at the base pose grown by ``px`` pixels (a square window)."""
    from scipy import ndimage

    D = eng.support()
    r = round(px)
    return np.stack([ndimage.maximum_filter(d > 0, size=2 * r + 1) if r else d > 0 for d in D])


def _rotvec(Rm: np.ndarray) -> np.ndarray:
    """``Rotation.from_matrix(Rm, assume_valid=True).as_rotvec()`` of rigid ``Rm (1, 3, 3)`` (float64,
    contiguous): where scipy has them, its NumPy backend's two functions that those call, without its
    array-API dispatch (the same functions on the same values: the same rotation vector; 12 -> 5 us on
    this 2-core x86_64 machine)."""
    global _CY
    if _CY is None:
        try:
            from scipy.spatial.transform import _rotation_cy as cy

            cy.as_rotvec(cy.from_matrix(np.eye(3)[None], assume_valid=True), degrees=False)
            _CY = cy
        except (ImportError, AttributeError, TypeError):  # (another scipy: its public path)
            _CY = False
    if _CY:
        return _CY.as_rotvec(_CY.from_matrix(Rm, assume_valid=True), degrees=False)
    from scipy.spatial.transform import Rotation

    try:  # (orthogonal within 1e-12: scipy's check would take the matrix as it is; a fifth of the time)
        return Rotation.from_matrix(Rm, assume_valid=True).as_rotvec()
    except TypeError:  # (a scipy without assume_valid)
        return Rotation.from_matrix(Rm).as_rotvec()


_CY = None  # (scipy's NumPy rotation backend, False where it has none: _rotvec)


def stage_params(pose: np.ndarray, center: np.ndarray, base: np.ndarray) -> np.ndarray:
    """:func:`core.geometry.transforms.params_from_pose` of one stage pose (rigid: made by the engine's
    :meth:`~core.tracking.engine_likelihood.LikelihoodEngine.poses`) about ``center`` relative to the
    rigid ``base``: the same arithmetic and values, without its checks of both transforms (a third of
    its time) and scipy's of the rotation's orthogonality (both rigid: 128 -> 26 us of scipy's on this
    2-core x86_64 machine)."""
    c = np.asarray(center, dtype=float)
    R, Rb = pose[:3, :3], base[:3, :3]
    Rm = (R @ np.swapaxes(Rb, -1, -2)).reshape(-1, 3, 3)
    rv = _rotvec(Rm).reshape(3)
    disp = (np.einsum("...ij,...j->...i", R, c) + pose[:3, 3] - np.einsum("...ij,...j->...i", Rb, c)
            - base[:3, 3])
    return np.concatenate([disp, rv])
