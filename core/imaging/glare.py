"""Veiling glare of an image intensifier: estimate it from a disc frame and undo it.

Model
-----
A fraction ``f`` of the light leaving the intensifier is spread over centimetres (scatter in the
output window and the optics): the fluence image seen by the camera is

``y = (1 - f) · x + f · G_σ ∗ x``

with ``x`` the glare-free image and ``G_σ`` a normalised Gaussian of σ pixels. The glare acts on
the fluence, before the log and before the intensifier's distortion, and the flatfield of an
empty field carries it uniformly, so after flatfield division ``y`` is the relative fluence
``I/I0`` and the model holds as written.

Estimate (:func:`estimate_glare`)
---------------------------------
The veiling-glare-index measurement: an opaque lead disc on the intensifier face, a few
centimetres across, in the middle of the field. Behind the disc the only light is glare, and
around it the open field lacks the glare the disc would have sent. The flatfield-normalised,
undistorted frame (or the mean of several) is reduced to its radial profile about the disc's
centre (found as the dark region's centroid, its radius from the area) and fitted by

``y(r) = a - b · D(r; R, σ_p) - c · D(r; R, σ)``

where ``D(r; R, s)`` is a disc of radius ``R`` blurred by a Gaussian of ``s`` evaluated at
radius ``r`` (the non-central χ² distribution with 2 degrees of freedom), ``σ_p`` the compact
PSF (a nuisance), ``a`` the open-field level, and ``f = c / (b + c)``, the disc's transmission
``1 - (b + c) / a``. ``a, b, c`` are solved linearly for every ``(σ_p, σ, R)``; pixels weigh by
their Poisson variance. A second pass leaves the edge out (``|r - R|`` within ``max(2, 4 σ_p)``
pixels, where the compact blur and the disc's exact outline dominate and any misfit would pull
σ) and refits σ with ``R`` and ``σ_p`` kept. The standard deviations come from the Jacobian.

Undo (:func:`remove_glare`, :class:`core.imaging.pipeline.GlareStep`)
---------------------------------------------------------------------
``x = (y - f · G_σ ∗ x) / (1 - f)`` with ``G_σ ∗ x = F⁻¹[Ĝ · Ŷ / ((1 - f) + f · Ĝ)]``: a
smooth image, computed by FFT on a grid downsampled so that σ spans about 4 cells (a 1024² frame
with σ = 70 px: a 64² grid), with the image mirrored at its borders and the pixels outside the
field (0 after flatfield division) filled from the nearest ones inside. Full-resolution detail
is never filtered, only the smooth glare is subtracted.

Pixels ``(u, v) = (column, row)``, origin at the centre of the top-left pixel.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import cv2
import numpy as np

from .._validate import positive

__all__ = ["GlareEstimate", "disc_profile", "estimate_glare", "remove_glare"]


@dataclass(frozen=True)
class GlareEstimate:
    """Veiling glare measured from a disc frame (:func:`estimate_glare`).

    Attributes
    ----------
    fraction, sigma_px : float
        Glare fraction ``f`` and Gaussian width σ (pixels of the frame it was measured on).
    fraction_sd, sigma_px_sd : float
        Their standard deviations from the fit (noise only).
    psf_sigma_px : float
        The compact blur at the disc's edge (Gaussian σ, pixels; includes the pixel footprint).
    transmission : float
        The disc's own transmission (≈ 0 for lead).
    scale : float
        The open-field level of the normalised frame (≈ 1).
    center_uv, radius_px : tuple, float
        The disc's centre and radius in the frame.
    rms : float
        RMS residual of the radial profile (relative fluence).
    n_frames, n_pixels : int
        Frames averaged and pixels in the profile.
    """

    fraction: float
    sigma_px: float
    fraction_sd: float
    sigma_px_sd: float
    psf_sigma_px: float
    transmission: float
    scale: float
    center_uv: tuple[float, float]
    radius_px: float
    rms: float
    n_frames: int
    n_pixels: int

    def to_dict(self, *, pixel_mm: float | None = None) -> dict:
        """Plain JSON; ``pixel_mm`` adds σ in mm."""
        d = asdict(self)
        d["center_uv"] = [float(c) for c in self.center_uv]
        if pixel_mm is not None:
            d["sigma_mm"] = float(self.sigma_px * pixel_mm)
            d["sigma_mm_sd"] = float(self.sigma_px_sd * pixel_mm)
        return d


# ---------------------------------------------------------------------------- the forward model
def disc_profile(r, radius: float, sigma: float) -> np.ndarray:
    """A disc of ``radius`` (1 inside, 0 outside) blurred by a Gaussian of ``sigma``, at radius ``r``
    from its centre (all in pixels): ``P(|r + X| < R)``, ``X ~ N(0, σ² I₂)``."""
    from scipy.special import chndtr, ndtr

    r = np.asarray(r, dtype=np.float64)
    s = positive(sigma, "sigma")
    if radius / s > 40:  # the edge is locally straight: the 1-D error function
        return ndtr((radius - r) / s)
    return chndtr((radius / s) ** 2, 2.0, (r / s) ** 2)


# ---------------------------------------------------------------------------- estimate
def _disc(img: np.ndarray, valid: np.ndarray) -> tuple[float, float, float]:
    """Centre ``(u, v)`` and radius of the largest dark region of ``img`` inside ``valid``."""
    from scipy import ndimage

    open_level = float(np.percentile(img[valid], 90))
    dark = valid & (img < 0.5 * open_level)
    lab, n = ndimage.label(dark)
    if n == 0:
        raise ValueError("images: no dark (opaque) region found: expected a frame of an opaque disc "
                         "(e.g. 2 mm of lead) inside the field")
    sizes = ndimage.sum_labels(dark, lab, index=np.arange(1, n + 1))
    k = int(np.argmax(sizes)) + 1
    region = lab == k
    grown = ndimage.binary_dilation(region, iterations=3)
    if np.any(grown & ~valid) or grown[0].any() or grown[-1].any() or grown[:, 0].any() or grown[:, -1].any():
        raise ValueError("images: the opaque disc touches the edge of the field: place it inside "
                         "the field, away from its rim")
    v, u = np.nonzero(region)
    return float(u.mean()), float(v.mean()), float(np.sqrt(region.sum() / np.pi))


def _profile(img, valid, cu, cv, r_max, bin_px):
    v, u = np.nonzero(valid)
    r = np.hypot(u - cu, v - cv)
    keep = r <= r_max
    r, y = r[keep], img[v[keep], u[keep]].astype(np.float64)
    k = (r / bin_px).astype(np.int64)
    n = np.bincount(k)
    ok = n > 0
    rm = np.bincount(k, weights=r)[ok] / n[ok]
    ym = np.bincount(k, weights=y)[ok] / n[ok]
    return rm, ym, n[ok].astype(np.float64), int(keep.sum())


def estimate_glare(images, *, mask=None, max_radius_px: float | None = None,
                   bin_px: float = 0.5) -> GlareEstimate:
    """Veiling glare from flatfield-normalised frames of an opaque disc (module docs).

    Parameters
    ----------
    images : (H, W) or (n, H, W) array
        Flatfield-normalised (``I/I0``), undistorted frames of an opaque disc (lead, a few cm
        across, well inside the field); several frames are averaged.
    mask : (H, W) bool, optional
        Usable pixels (True), e.g. the intensifier's field; default all.
    max_radius_px : float, optional
        Profile radius; default the distance from the disc's centre to the nearest image border.
    bin_px : float
        Radial bin width of the profile, pixels.

    Returns
    -------
    GlareEstimate

    Raises
    ------
    ValueError
        No opaque region, a disc touching the field's edge, or a profile too short to fit.
    """
    from scipy.optimize import least_squares

    a = np.asarray(images, dtype=np.float64)
    if a.ndim == 2:
        a = a[None]
    if a.ndim != 3 or min(a.shape[1:]) < 16:
        raise ValueError(f"images: expected (H, W) or (n, H, W) frames, got shape {a.shape}")
    img = a.mean(axis=0)
    valid = np.isfinite(img) if mask is None else (np.asarray(mask, bool) & np.isfinite(img))
    if valid.shape != img.shape:
        raise ValueError(f"mask: expected shape {img.shape}, got {valid.shape}")
    cu, cv, R0 = _disc(img, valid)
    h, w = img.shape
    r_max = float(max_radius_px) if max_radius_px is not None else min(cu, cv, w - 1 - cu, h - 1 - cv)
    if r_max < 1.5 * R0:
        raise ValueError(f"max_radius_px: the profile ({r_max:.0f} px) must reach well beyond the disc "
                         f"(radius {R0:.0f} px)")
    r, y, n, n_px = _profile(img, valid, cu, cv, r_max, positive(bin_px, "bin_px"))
    wt = np.sqrt(n / np.maximum(y, 0.01))  # Poisson weights, first from the data, then from the fit

    def design(p):
        sp, sg, R = np.exp(p[0]), np.exp(p[1]), p[2]
        return np.stack([np.ones_like(r), -disc_profile(r, R, sp), -disc_profile(r, R, sg)], axis=1)

    def solve(p):
        A = design(p)
        coef, *_ = np.linalg.lstsq(A * wt[:, None], y * wt, rcond=None)
        return coef, (A @ coef - y) * wt

    bounds = ([np.log(0.05), np.log(1.0), 0.5 * R0], [np.log(R0 / 3), np.log(4 * r_max), 1.5 * R0])
    best = None
    for s0 in (0.25, 0.5, 1.0, 2.0):
        p0 = np.array([0.0, np.log(max(s0 * R0, 3.0)), R0])
        res = least_squares(lambda p: solve(p)[1], p0, x_scale=[0.3, 0.3, 0.5], bounds=bounds)
        if best is None or res.cost < best.cost:
            best = res
    # second pass: the edge itself (where the compact blur and the disc's exact outline dominate)
    # left out, σ refitted with the edge's radius and blur kept; weights from the first fit
    sp, R = best.x[0], best.x[2]
    band = max(2.0, 4 * float(np.exp(sp)))
    wt = np.where(np.abs(r - R) > band, np.sqrt(n / np.maximum(design(best.x) @ solve(best.x)[0], 0.01)), 0.0)
    res = least_squares(lambda q: solve([sp, q[0], R])[1], best.x[1:2], x_scale=[0.3],
                        bounds=([bounds[0][1]], [bounds[1][1]]))
    p = np.array([sp, res.x[0], R])
    coef, resid = solve(p)
    # covariance of (a, b, c, log σ) from the Jacobian
    full = np.r_[coef, p[1]]

    def model4(q):
        return (design([sp, q[3], R]) @ q[:3] - y) * wt

    J = np.empty((len(y), 4))
    for i in range(4):
        hstep = 1e-5 * max(abs(full[i]), 1.0)
        e = np.zeros(4)
        e[i] = hstep
        J[:, i] = (model4(full + e) - model4(full - e)) / (2 * hstep)
    s2 = float(resid @ resid) / max(int(np.count_nonzero(wt)) - 4, 1)
    C = s2 * np.linalg.pinv(J.T @ J)
    av, b, c = coef
    f = c / (b + c)
    gf = np.array([0.0, -c / (b + c) ** 2, b / (b + c) ** 2, 0])
    sg = float(np.exp(p[1]))
    fit = design(p) @ coef
    keep = wt > 0
    return GlareEstimate(
        fraction=float(f), sigma_px=sg, fraction_sd=float(np.sqrt(gf @ C @ gf)),
        sigma_px_sd=float(sg * np.sqrt(C[3, 3])), psf_sigma_px=float(np.exp(p[0])),
        transmission=float(1 - (b + c) / av), scale=float(av), center_uv=(cu, cv), radius_px=float(p[2]),
        rms=float(np.sqrt(np.sum((n * (fit - y) ** 2)[keep]) / n[keep].sum())), n_frames=int(a.shape[0]),
        n_pixels=n_px)


# ---------------------------------------------------------------------------- undo
def _fill_outside(small: np.ndarray, ok: np.ndarray) -> np.ndarray:
    from scipy import ndimage

    if ok.all():
        return small
    if not ok.any():
        return np.zeros_like(small)
    idx = ndimage.distance_transform_edt(~ok, return_distances=False, return_indices=True)
    return small[tuple(idx)]


def remove_glare(image, fraction: float, sigma_px: float, *, downsample: int | None = None,
                 clip: tuple[float, float] | None = (0.0, 1.0)) -> np.ndarray:
    """The glare-free image ``x`` of a flatfield-normalised frame ``y`` (module docs); float32.

    ``downsample``: grid factor of the smooth part (default ``max(1, σ // 4)``). Pixels at 0 (outside
    the field) stay 0 and do not count as dark scene. ``clip``: output range (None = none).
    """
    y = np.asarray(image, dtype=np.float32)
    if y.ndim != 2:
        raise ValueError(f"image: expected a 2-D frame, got shape {y.shape}")
    f = float(fraction)
    if not 0 <= f < 1:
        raise ValueError(f"fraction: expected a glare fraction in [0, 1), got {fraction!r}")
    s = positive(sigma_px, "sigma_px")
    if f == 0:
        out = y.copy()
    else:
        d = max(1, int(s // 4)) if downsample is None else int(downsample)
        if d < 1:
            raise ValueError(f"downsample: expected an integer >= 1, got {downsample!r}")
        h, w = y.shape
        inside = y > 0
        hs, ws = max(1, round(h / d)), max(1, round(w / d))
        num = cv2.resize(np.maximum(y, 0.0), (ws, hs), interpolation=cv2.INTER_AREA).astype(np.float64)
        den = cv2.resize(inside.astype(np.float32), (ws, hs), interpolation=cv2.INTER_AREA).astype(np.float64)
        ok = den > 0.25
        small = _fill_outside(np.where(ok, num / np.where(ok, den, 1.0), 0.0), ok)
        sy, sx = s * hs / h, s * ws / w
        pad = int(np.ceil(4 * max(sy, sx)))
        big = np.pad(small, pad, mode="symmetric")
        fy = np.fft.fftfreq(big.shape[0])[:, None]
        fx = np.fft.rfftfreq(big.shape[1])[None, :]
        G = np.exp(-2 * np.pi**2 * ((sy * fy) ** 2 + (sx * fx) ** 2))
        smooth = np.fft.irfft2(np.fft.rfft2(big) * (G / ((1 - f) + f * G)), s=big.shape)
        smooth = np.ascontiguousarray(smooth[pad:pad + hs, pad:pad + ws], dtype=np.float32)
        glare = cv2.resize(smooth, (w, h), interpolation=cv2.INTER_LINEAR)
        out = (y - np.float32(f) * glare) * np.float32(1 / (1 - f))
        out[~inside] = 0.0
    if clip is not None:
        np.clip(out, clip[0], clip[1], out=out)
    return out
