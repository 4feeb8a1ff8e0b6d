"""Beads of a calibration object in a corrected frame: detection, localisation, size classes.

Detection and sub-pixel localisation are :mod:`core.markers`' (scale-space blobs that are round
and of the right size, thesis §5.4.2's "threshold + circularity + size"; the recommended
localizer of Chapter 4). What calibration adds is the *apparent size* of each bead, which carries
its identity (3.0 vs 5.0 mm beads of a spiral; the cube's 1.78 / 3.17 / 4.76 mm planes):

* ``size_px``: the equivalent diameter ``2 sqrt(A / π)`` of the bead's "dark area"
  ``A = Σ (b - I) / b`` over a disc of 1.6 radii, ``b`` the local background (median of the
  ring 1.9-2.7 radii). Blur moves light around but keeps this integral, so it measures the
  projected bead far better than the blob scale; for opaque beads it is the projected diameter.
* :func:`classify_sizes` finds the common scale (px per mm, i.e. magnification / pixel pitch)
  that best maps the measured sizes onto the object's nominal diameters and labels each bead
  with its size class; sizes that fit no class (two beads overlapping, a bead on an edge) are
  class ``-1``.

Pixels are ``(u, v) = (column, row)``, origin at the centre of the top-left pixel.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validate import as_float_array, positive
from ..markers import detect_beads, localize
from ..markers.results import STATUS

__all__ = ["ObjectDetections", "background_normalised", "classify_sizes", "detect_object_beads",
           "equivalent_diameters"]


@dataclass(frozen=True, eq=False)
class ObjectDetections:
    """Bead detections of one view.

    Attributes
    ----------
    uv : (m, 2)
        Sub-pixel centres, px.
    sigma : (m, 2)
        Their uncertainty (px; NaN when the localizer gave none).
    size_px : (m,)
        Equivalent diameter of the bead's dark area, px.
    size_class : (m,) int
        Index into ``nominal_mm`` (ascending), -1 for a size that fits no class.
    px_per_mm : float
        Fitted scale: projected diameter (px) per bead diameter (mm).
    nominal_mm : (k,)
        The object's distinct bead diameters, mm.
    snr : (m,)
        Detection contrast over the pixel noise.
    """

    uv: np.ndarray
    sigma: np.ndarray
    size_px: np.ndarray
    size_class: np.ndarray
    px_per_mm: float
    nominal_mm: np.ndarray
    snr: np.ndarray

    def __len__(self) -> int:
        return len(self.uv)

    def without(self, index) -> ObjectDetections:
        """A copy with the detections ``index`` removed (e.g. to simulate missed beads)."""
        keep = np.setdiff1d(np.arange(len(self)), np.atleast_1d(index))
        return ObjectDetections(self.uv[keep], self.sigma[keep], self.size_px[keep],
                                self.size_class[keep], self.px_per_mm, self.nominal_mm, self.snr[keep])


def equivalent_diameters(image, uv, radius_px, *, polarity: str = "dark") -> np.ndarray:
    """Equivalent diameter (px) of the dark (or bright) area of each bead (module docstring).

    ``uv (m, 2)`` centres, ``radius_px`` scalar or ``(m,)`` rough radii in pixels.
    """
    img = np.asarray(image, dtype=np.float64)
    if img.ndim != 2:
        raise ValueError(f"image: expected a 2-D image, got shape {img.shape}")
    pts = as_float_array(uv, "uv", shape=(None, 2))
    r = np.broadcast_to(np.asarray(radius_px, dtype=float), (len(pts),))
    sign = 1.0 if polarity == "dark" else -1.0
    H, W = img.shape
    out = np.full(len(pts), np.nan)
    for i, ((u, v), ri) in enumerate(zip(pts, r, strict=True)):
        h = int(np.ceil(2.8 * ri)) + 1
        u0, v0 = round(float(u)), round(float(v))
        r0, r1, c0, c1 = max(v0 - h, 0), min(v0 + h + 1, H), max(u0 - h, 0), min(u0 + h + 1, W)
        win = img[r0:r1, c0:c1]
        yy, xx = np.mgrid[r0:r1, c0:c1]
        d = np.hypot(xx - u, yy - v)
        ring = (d >= 1.9 * ri) & (d <= 2.7 * ri)
        disc = d <= 1.6 * ri
        if ring.sum() < 8 or not disc.any():
            continue
        b = np.median(win[ring])
        if b == 0:
            continue
        area = np.sum(sign * (b - win[disc]) / abs(b))
        out[i] = 2.0 * np.sqrt(max(area, 0.0) / np.pi)
    return out


def classify_sizes(size_px, nominal_mm, *, tolerance: float = 0.18,
                   scale_range: tuple[float, float] | None = None) -> tuple[np.ndarray, float]:
    """Size class of every bead from its apparent size.

    Parameters
    ----------
    size_px : (m,) array
        Apparent diameters, px (NaN = unknown).
    nominal_mm : (k,) array
        Distinct bead diameters of the object, mm.
    tolerance : float
        Largest accepted ``|log(size / (scale · nominal))|`` (0.18 ≈ ±20 %).
    scale_range : (lo, hi), optional
        Plausible px per mm; default any.

    Returns
    -------
    classes : (m,) int
        Index into the ascending ``nominal_mm``; -1 when no class fits.
    px_per_mm : float
        The scale that explains the most sizes (median ratio over them); NaN if none.
    """
    s = as_float_array(size_px, "size_px", finite=False).ravel()
    nom = np.sort(as_float_array(nominal_mm, "nominal_mm").ravel())
    if nom.size == 0 or np.any(nom <= 0):
        raise ValueError("nominal_mm: expected positive bead diameters")
    ok = np.isfinite(s) & (s > 0)
    cls = np.full(len(s), -1)
    if not ok.any():
        return cls, float("nan")
    ls, ln = np.log(s[ok]), np.log(nom)
    cands = (ls[:, None] - ln[None]).ravel()  # log scale hypotheses
    if scale_range is not None:
        lo = np.log(positive(scale_range[0], "scale_range"))
        hi = np.log(positive(scale_range[1], "scale_range"))
        cands = cands[(cands >= lo) & (cands <= hi)]
        if cands.size == 0:
            return cls, float("nan")
    dev = np.abs(ls[None, :, None] - cands[:, None, None] - ln[None, None, :]).min(axis=2)
    score = (dev <= tolerance).sum(axis=1) - 1e-3 * np.where(dev <= tolerance, dev, 0).sum(axis=1)
    best = cands[np.argmax(score)]
    for _ in range(3):  # re-centre on the inliers
        d = ls[:, None] - best - ln[None]
        k = np.argmin(np.abs(d), axis=1)
        inl = np.abs(d[np.arange(len(k)), k]) <= tolerance
        if not inl.any():
            break
        best = float(np.median(ls[inl] - ln[k[inl]]))
    d = ls[:, None] - best - ln[None]
    k = np.argmin(np.abs(d), axis=1)
    k[np.abs(d[np.arange(len(k)), k]) > tolerance] = -1
    cls[ok] = k
    return cls, float(np.exp(best))


def background_normalised(image, bead_px: float, *, polarity: str = "dark") -> np.ndarray:
    """``image`` divided by its local background: a grey closing (an opening for bright beads)
    with a disc of about 1.4 ``bead_px`` (the largest bead's diameter), which fills the beads and
    keeps what is larger than them (a calibration object's body, its edges and end caps). A bead
    then sits on a flat background of 1, which the localizer's plane does model: on noise-free
    renders of the 33-bead spiral inside its tube the background's edges had stretched each
    frame's bead pattern along the spiral's axis by up to 0.06 %, and that stretch went straight
    into the focal lengths. Pixels with no background (outside the field) are 1."""
    import cv2

    img = np.asarray(image, dtype=np.float32)
    k = int(2 * np.ceil(0.7 * float(bead_px)) + 1)
    se = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k))
    bg = cv2.morphologyEx(img, cv2.MORPH_CLOSE if polarity == "dark" else cv2.MORPH_OPEN, se)
    scale = max(float(np.percentile(np.abs(bg), 99)), 1e-12)
    ok = np.abs(bg) > 1e-3 * scale
    return np.where(ok, img / np.where(ok, bg, 1.0), 1.0).astype(np.float32)


def detect_object_beads(image, nominal_mm, *, px_per_mm: float, polarity: str = "dark",
                        min_snr: float = 6.0, mask=None, max_beads: int | None = None,
                        flatten_background: bool = False) -> ObjectDetections:
    """Detect, localise and size-classify the beads of a calibration object in one view.

    Parameters
    ----------
    image : (H, W) array
        Flatfield-corrected (and distortion-corrected) frame.
    nominal_mm : sequence of float
        The object's bead diameters (mm), e.g. ``target.size_classes[0]``.
    px_per_mm : float
        Rough projected size of 1 mm at the object (magnification / pixel pitch, e.g.
        ``f / source-object distance``); ±30 % is enough.
    polarity : {"dark", "bright"}
    min_snr : float
        Detection threshold (:func:`core.markers.detect_beads`).
    mask : (H, W) bool, optional
        Where beads may be.
    max_beads : int, optional
        Keep at most this many (strongest).
    flatten_background : bool
        Localise on the frame divided by its local background (:func:`background_normalised`):
        for an object whose body has edges near its beads (the spiral's tube and end caps).

    Returns
    -------
    ObjectDetections
    """
    nom = np.sort(np.unique(as_float_array(nominal_mm, "nominal_mm").ravel()))
    scale = positive(px_per_mm, "px_per_mm")
    dmin, dmax = nom[0] * scale, nom[-1] * scale
    gm = float(np.sqrt(dmin * dmax))
    det = detect_beads(image, diameter_px=gm, polarity=polarity, min_snr=min_snr,
                       size_range=(0.75 * dmin / gm, 1.35 * dmax / gm), mask=mask, refine=False,
                       max_beads=max_beads)
    m = len(det)
    empty = np.zeros(0)
    if m == 0:
        return ObjectDetections(np.zeros((0, 2)), np.zeros((0, 2)), empty, np.zeros(0, np.int64),
                                float("nan"), nom, empty)
    size0 = equivalent_diameters(image, det.uv, det.radius, polarity=polarity)
    size0 = np.where(np.isfinite(size0), size0, 2 * det.radius)
    # localise each bead with its own size and the localizer's default search window, on the frame
    # divided by its local background (the object's body, its edges and end caps)
    flat = background_normalised(image, 1.35 * dmax, polarity=polarity) if flatten_background else image
    loc = localize(flat, det.uv, diameter_px=np.clip(size0, 2.0, None), polarity=polarity, min_snr=3.0)
    good = loc.status == STATUS["ok"]
    uv = np.where(good[:, None], loc.uv, det.uv)
    sigma = np.where(good[:, None], loc.sigma, np.nan)
    size = equivalent_diameters(image, uv, np.where(np.isfinite(size0), size0 / 2, det.radius),
                                polarity=polarity)
    cls, fitted = classify_sizes(size, nom, scale_range=(scale / 1.6, scale * 1.6))
    return ObjectDetections(uv, sigma, size, cls, fitted, nom, det.snr)
