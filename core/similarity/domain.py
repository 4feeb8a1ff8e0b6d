"""The comparison domain Ω and the preparation of a fluoroscope ROI for comparison with DRRs.

Conventions shared by every metric of :mod:`core.similarity`
-----------------------------------------------------------
* A DRR holds line integrals of attenuation (unitless, bone bright, 0 off the bone). A
  flatfield-normalised fluoroscope image holds relative fluence in [0, 1] (bone dark). The two are
  compared in the same polarity: :func:`line_integral_image` turns the fluoroscope image into
  ``-ln(I/I0)``, the line integral of everything in the beam (bone + soft tissue + …), so the
  bone's contribution adds to it exactly as in the DRR. Metrics that are invariant to the
  intensity transform (MI, NMI, GO) do not need it; the others do.
* Both images are ``(h, w)`` arrays of the same ROI, pixel ``[r, c]`` of one matching pixel
  ``[r, c]`` of the other; :func:`sample_roi` samples a full fluoroscope frame at the ray
  positions of a :class:`core.render.DRRBatch` item.
* Ω (thesis §6.2) is the set of DRR bone pixels ``DRR > threshold`` (default 0), optionally
  dilated by ``dilate`` pixels (a square of side ``2·dilate + 1``: the bone's outline is then
  inside Ω with both of its sides, which gradient metrics use), and intersected with an optional
  ``fluoro_mask`` (True = usable fluoroscope pixel; e.g. False on beads, outside the intensifier's
  round field, or on a pressure plate).
* ``fluoro_sigma`` (pixels) smooths the fluoroscope ROI with a Gaussian before comparison (the
  DRR is noise-free; the fluoroscope ROI is smoothed once per frame, not per pose).

Bad input: shapes that differ, non-2-D images or NaN/infinite pixels raise ``ValueError`` naming
the argument. An empty Ω, or images without variation inside Ω, give the score 0.0 (no evidence
of similarity) — every metric documents where its normalisation is undefined.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import ndimage

from .._validate import as_float_array

__all__ = ["domain", "line_integral_image", "sample_roi"]


def _nonneg_int(value, name: str) -> int:
    if isinstance(value, bool) or int(value) != value or value < 0:
        raise ValueError(f"{name}: expected an integer >= 0, got {value!r}")
    return int(value)


def _nonneg_float(value, name: str) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name}: expected a number >= 0, got {value!r}") from exc
    if not np.isfinite(v) or v < 0:
        raise ValueError(f"{name}: expected a finite number >= 0, got {value!r}")
    return v


def check_pair(drr, fluoro) -> tuple[np.ndarray, np.ndarray]:
    """Validate a DRR / fluoroscope ROI pair: float64, 2-D, same shape, finite."""
    d = as_float_array(drr, "drr", ndim=2)
    f = as_float_array(fluoro, "fluoro", ndim=2)
    if d.shape != f.shape:
        raise ValueError(f"fluoro: expected the DRR's shape {d.shape}, got {f.shape}")
    if d.size == 0:
        raise ValueError("drr: expected a non-empty image")
    return d, f


def domain(drr, *, threshold: float = 0.0, dilate: int = 0, fluoro_mask=None) -> np.ndarray:
    """Ω as a boolean ``(h, w)`` mask: ``drr > threshold``, dilated by ``dilate`` px, ∩ ``fluoro_mask``.

    Parameters
    ----------
    drr : (h, w) array
        DRR line integrals.
    threshold : float
        Bone pixels are those strictly above it (default 0: any attenuation on the ray).
    dilate : int
        Chebyshev (square) dilation radius in pixels; it does not reach past the image border.
    fluoro_mask : (h, w) bool array, optional
        True where the fluoroscope pixel may be used.
    """
    d = as_float_array(drr, "drr", ndim=2)
    thr = float(threshold)
    if not np.isfinite(thr):
        raise ValueError(f"threshold: expected a finite number, got {threshold!r}")
    k = _nonneg_int(dilate, "dilate")
    om = d > thr
    if k:
        om = ndimage.maximum_filter(om, size=2 * k + 1, mode="constant", cval=False)
    if fluoro_mask is not None:
        m = np.asarray(fluoro_mask)
        if m.shape != d.shape or m.dtype != bool:
            raise ValueError(
                f"fluoro_mask: expected a bool array of shape {d.shape}, got {m.dtype} {m.shape}")
        om &= m
    return om


def prepare(drr, fluoro, *, threshold: float = 0.0, dilate: int = 0, fluoro_mask=None,
            fluoro_sigma: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(drr, fluoro, Ω)`` after validation and the optional fluoroscope smoothing."""
    d, f = check_pair(drr, fluoro)
    s = _nonneg_float(fluoro_sigma, "fluoro_sigma")
    if s > 0:
        f = ndimage.gaussian_filter(f, s, mode="nearest")
    return d, f, domain(d, threshold=threshold, dilate=dilate, fluoro_mask=fluoro_mask)


def line_integral_image(fluoro, *, floor: float = 1.0 / 4096) -> np.ndarray:
    """``-ln(clip(fluoro, floor, 1))`` as float32: a flatfield-normalised image in DRR polarity.

    ``floor`` (relative fluence, > 0; default one 12-bit level) bounds the result at
    ``-ln(floor)`` where the image is black (beads, collimator, outside the field).
    """
    f = as_float_array(fluoro, "fluoro", finite=False)
    if np.any(np.isnan(f)):
        raise ValueError("fluoro: contains NaN values")
    lo = float(floor)
    if not 0 < lo < 1:
        raise ValueError(f"floor: expected a relative fluence in (0, 1), got {floor!r}")
    return (-np.log(np.clip(f, lo, 1.0))).astype(np.float32)


def sample_roi(image, roi, *, scale: float = 1.0) -> np.ndarray:
    """Sample ``image`` at the pixel positions of a DRR ROI (as :class:`core.render.DRRBatch`).

    Output pixel ``[r, c]`` is the bilinear sample at ``(u, v) = (u0 + (c + 0.5)·s - 0.5,
    v0 + (r + 0.5)·s - 0.5)`` (borders replicate), shape ``(ceil(h / s), ceil(w / s))``, float32.

    Parameters
    ----------
    image : (H, W) array
        A full frame (e.g. :func:`line_integral_image` of a fluoroscope frame).
    roi : (4,) ints
        ``(u0, v0, w, h)`` in full-resolution pixels.
    scale : float
        Full-resolution pixels per output pixel ``s`` (> 0).
    """
    img = as_float_array(image, "image", ndim=2, dtype=np.float32)
    r = np.asarray(roi)
    if r.shape != (4,) or not np.issubdtype(r.dtype, np.integer) or np.any(r[2:] <= 0):
        raise ValueError(f"roi: expected integer (u0, v0, w, h) with w, h > 0, got {roi!r}")
    s = float(scale)
    if not np.isfinite(s) or s <= 0:
        raise ValueError(f"scale: expected a positive number of pixels, got {scale!r}")
    import cv2  # only here: the device metrics and the benchmark do not need OpenCV

    u0, v0, w, h = (int(a) for a in r)
    ho, wo = math.ceil(h / s), math.ceil(w / s)
    cc = (u0 + (np.arange(wo, dtype=np.float32) + 0.5) * s - 0.5).astype(np.float32)
    rr = (v0 + (np.arange(ho, dtype=np.float32) + 0.5) * s - 0.5).astype(np.float32)
    mu, mv = np.meshgrid(cc, rr)
    return cv2.remap(img, mu, mv, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
