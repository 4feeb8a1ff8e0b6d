"""Flatfield (brightness non-uniformity) correction of image-intensifier frames (thesis §3.3).

Estimate
--------
Empty-field frames taken at the trial's kV/mA are averaged over time (random noise), the dark
level is subtracted (a dark frame, a scalar, or 0) and the mean is smoothed into the fluence
surface ``G = I0 - dark``:

* ``"max"`` (default, the thesis's): a sliding **maximum** over a ``kernel_size`` square
  followed by a sliding minimum of the same size (together a grey *closing*), then a box mean
  of that size to round off the plateaus. The surface follows the upper envelope of the
  remaining noise, so it approximates the *maximum* fluence: normalised empty frames read
  slightly below 1. The minimum step matters: a sliding maximum alone also shifts the surface
  half a kernel towards the brighter centre, a bias that grows with the roll-off slope (3 %
  at the corners of a 0.65-edge field with a 15 px kernel, against < 1 % with the closing).
* ``"mean"`` / ``"median"``: a box mean / median of ``kernel_size``.
* ``"polynomial"``: a least-squares 2-D Chebyshev surface of total degree ``order`` fitted to
  a block-averaged copy, with ``mask`` (True = contaminated: hardware in the beam) left out and,
  optionally, robust rejection of blocks far *below* the surface (an unmasked strain gauge).
* ``"spline"``: a smoothing bicubic spline (:class:`scipy.interpolate.LSQBivariateSpline`, knots
  every ``knot_spacing_px``) fitted to the same masked block averages.

Normalise
---------
:meth:`Flatfield.normalise` turns a raw frame into float32 ``I/I0 = (DN - dark) / G`` in [0, 1]
(1 = full fluence, DESIGN.md). Pixels where ``G`` is not positive (outside a round field, a dead
region) cannot be normalised: they are reported (:attr:`Flatfield.n_invalid`,
:attr:`Flatfield.valid`) and set to 0. One flatfield per tube voltage: :class:`FlatfieldLibrary`.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.interpolate import LSQBivariateSpline
from scipy.ndimage import median_filter

from .._validate import positive
from .serialize import decode_array, encode_array

__all__ = ["METHODS", "Flatfield", "FlatfieldLibrary", "build_flatfield", "fit_surface"]

METHODS = ("max", "mean", "median", "polynomial", "spline")


def _stack_mean(frames, name: str) -> np.ndarray:
    a = np.asarray(frames)
    if a.ndim == 2:
        a = a[None]
    if a.ndim != 3 or a.shape[0] == 0 or min(a.shape[1:]) < 4:
        raise ValueError(f"{name}: expected (H, W) or (n, H, W) frames, got shape {a.shape}")
    if not np.issubdtype(a.dtype, np.number) or np.iscomplexobj(a):
        raise ValueError(f"{name}: expected real numbers, got dtype {a.dtype}")
    m = a.mean(axis=0, dtype=np.float64)
    if not np.all(np.isfinite(m)):
        raise ValueError(f"{name}: contains NaN or infinite values")
    return m


def _odd(k, name: str) -> int:
    if int(k) != k or k < 1 or k % 2 == 0:
        raise ValueError(f"{name}: expected an odd integer >= 1, got {k!r}")
    return int(k)


def _cheb_design(x: np.ndarray, y: np.ndarray, order: int) -> np.ndarray:
    tx = np.polynomial.chebyshev.chebvander(x, order)
    ty = np.polynomial.chebyshev.chebvander(y, order)
    return np.column_stack([tx[:, i] * ty[:, j] for j in range(order + 1) for i in range(order + 1 - j)])


def fit_surface(image, *, method: str = "polynomial", mask=None, order: int = 6, block: int = 8,
                knot_spacing_px: float = 128.0, reject_sigma: float | None = 3.0) -> np.ndarray:
    """Smooth surface through ``image`` ((H, W) float) with ``mask`` (True = ignore) left out.

    ``method`` is "polynomial" (Chebyshev, total degree ``order``) or "spline" (bicubic, knots
    every ``knot_spacing_px``). Data are ``block``-averaged first; with ``reject_sigma`` blocks
    lower than the surface by more than that many robust σ are dropped and the fit repeated
    (twice), which removes unmasked attenuating hardware.
    """
    img = np.asarray(image, dtype=np.float64)
    H, W = img.shape
    bad = np.zeros(img.shape, bool) if mask is None else np.asarray(mask, bool)
    if bad.shape != img.shape:
        raise ValueError(f"mask: expected shape {img.shape}, got {bad.shape}")
    b = int(block)
    hb, wb = H // b, W // b
    good = (~bad[: hb * b, : wb * b]).reshape(hb, b, wb, b)
    vals = img[: hb * b, : wb * b].reshape(hb, b, wb, b)
    cnt = good.sum(axis=(1, 3))
    avg = np.where(cnt > 0, (vals * good).sum(axis=(1, 3)) / np.maximum(cnt, 1), 0.0)
    keep = cnt >= 0.5 * b * b
    vc = (np.arange(hb) * b + (b - 1) / 2)[:, None] * np.ones(wb)
    uc = np.ones(hb)[:, None] * (np.arange(wb) * b + (b - 1) / 2)
    sx, sy = 2.0 / max(W - 1, 1), 2.0 / max(H - 1, 1)

    def fit(sel):
        u, v, z = uc[sel], vc[sel], avg[sel]
        if method == "polynomial":
            n_terms = (order + 1) * (order + 2) // 2
            if sel.sum() < n_terms:
                raise ValueError(f"mask: only {int(sel.sum())} unmasked blocks for {n_terms} surface terms")
            c = np.linalg.lstsq(_cheb_design(u * sx - 1, v * sy - 1, order), z, rcond=None)[0]
            return lambda uu, vv: (_cheb_design(np.ravel(uu) * sx - 1, np.ravel(vv) * sy - 1, order)
                                   @ c).reshape(np.shape(uu))
        if method == "spline":
            step = positive(knot_spacing_px, "knot_spacing_px")
            tx = np.arange(step, W - 1 - step / 2, step)
            ty = np.arange(step, H - 1 - step / 2, step)
            spl = LSQBivariateSpline(u, v, z, tx, ty, bbox=[-0.5, W - 0.5, -0.5, H - 0.5], kx=3, ky=3)
            return lambda uu, vv: spl.ev(uu, vv)
        raise ValueError(f"method: expected 'polynomial' or 'spline', got {method!r}")

    if method == "polynomial" and (int(order) != order or not 0 <= order <= 20):
        raise ValueError(f"order: expected an integer in 0..20, got {order!r}")
    f = fit(keep)
    for _ in range(2 if reject_sigma else 0):
        r = avg - f(uc, vc)
        s = 1.4826 * np.median(np.abs(r[keep] - np.median(r[keep])))
        new = keep & (r > -float(reject_sigma) * max(s, 1e-12))
        if new.sum() == keep.sum():
            break
        keep = new
        f = fit(keep)
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    return f(u.ravel(), v.ravel()).reshape(H, W)


@dataclass(frozen=True, eq=False)
class Flatfield:
    """A flatfield: fluence surface ``gain = I0 - dark`` (DN) and the dark level.

    Attributes
    ----------
    gain : (H, W) float32
        Signal of full fluence above dark, DN; ``<= 0`` where there is none.
    dark : float or (H, W) float32
        Dark level subtracted from frames, DN.
    method, kernel_size : str, int
        How the surface was smoothed.
    n_frames : int
        Empty-field frames averaged.
    kv : float or None
        Tube voltage the flatfield belongs to.
    """

    gain: np.ndarray
    dark: float | np.ndarray = 0.0
    method: str = "max"
    kernel_size: int = 15
    n_frames: int = 1
    kv: float | None = None

    @property
    def shape(self) -> tuple[int, int]:
        return self.gain.shape

    @property
    def valid(self) -> np.ndarray:
        """``(H, W)`` bool: pixels with a positive fluence surface."""
        return self.gain > 0

    @property
    def n_invalid(self) -> int:
        """Pixels with no signal in the flatfield (normalised to 0)."""
        return int(np.count_nonzero(~self.valid))

    def subtract_dark(self, frame) -> np.ndarray:
        """``frame - dark`` as float32."""
        return np.asarray(frame, dtype=np.float32) - np.asarray(self.dark, dtype=np.float32)

    def divide(self, frame_minus_dark) -> np.ndarray:
        """``clip(frame_minus_dark / gain, 0, 1)`` float32 (0 where the flatfield is invalid)."""
        x = np.asarray(frame_minus_dark, dtype=np.float32)
        if x.shape != self.shape:
            raise ValueError(f"frame: expected shape {self.shape} (the flatfield's), got {x.shape}")
        ok = self.valid
        out = np.zeros(self.shape, np.float32)
        np.divide(x, self.gain, out=out, where=ok)
        return np.clip(out, 0.0, 1.0, out=out)

    def normalise(self, frame) -> np.ndarray:
        """Raw frame (DN) → float32 ``I/I0`` in [0, 1]."""
        return self.divide(self.subtract_dark(frame))

    def to_dict(self, *, array_encoder=encode_array) -> dict:
        """Plain-JSON form; arrays go through ``array_encoder`` (default: inline base64)."""
        dark = float(self.dark) if np.ndim(self.dark) == 0 else array_encoder(np.asarray(self.dark))
        return {"type": "flatfield", "gain": array_encoder(self.gain), "dark": dark, "method": self.method,
                "kernel_size": self.kernel_size, "n_frames": self.n_frames, "kv": self.kv}

    @classmethod
    def from_dict(cls, d: dict, *, array_decoder=decode_array) -> Flatfield:
        if d.get("type") != "flatfield":
            raise ValueError(f"d: expected a dict written by Flatfield.to_dict, got type {d.get('type')!r}")
        dark = d["dark"] if isinstance(d["dark"], int | float) else array_decoder(d["dark"])
        return cls(np.asarray(array_decoder(d["gain"]), np.float32), dark, d["method"], int(d["kernel_size"]),
                   int(d["n_frames"]), None if d.get("kv") is None else float(d["kv"]))


def build_flatfield(frames, *, dark=None, method: str = "max", kernel_size: int = 15, mask=None,
                    order: int = 6, knot_spacing_px: float = 128.0, kv: float | None = None,
                    min_signal: float = 1.0) -> Flatfield:
    """Estimate the flatfield from empty-field frames (see the module docs).

    Parameters
    ----------
    frames : (H, W) or (n, H, W) array_like
        Raw empty-field frames (DN), averaged over time.
    dark : float, (H, W) or (m, H, W) array_like, optional
        Dark level: a scalar, a dark frame or a stack of dark frames (averaged). Default 0.
    method : {"max", "mean", "median", "polynomial", "spline"}
    kernel_size : int
        Odd side of the sliding kernel (pixels) for max/mean/median.
    mask : (H, W) bool, optional
        True where hardware contaminates the field (surface fits only).
    order, knot_spacing_px : int, float
        Polynomial degree / spline knot spacing of the surface fits.
    kv : float, optional
        Tube voltage, for a :class:`FlatfieldLibrary`.
    min_signal : float
        Surface values below this (DN above dark) count as no signal and are set to 0.
    """
    if method not in METHODS:
        raise ValueError(f"method: expected one of {METHODS}, got {method!r}")
    mean = _stack_mean(frames, "frames")
    n = 1 if np.ndim(frames) == 2 else int(np.shape(frames)[0])
    if dark is None:
        dk: float | np.ndarray = 0.0
    elif np.ndim(dark) == 0:
        dk = float(dark)
        if not np.isfinite(dk):
            raise ValueError(f"dark: expected a finite level, got {dark!r}")
    else:
        dk = _stack_mean(dark, "dark").astype(np.float32)
        if dk.shape != mean.shape:
            raise ValueError(f"dark: expected frames of shape {mean.shape}, got {dk.shape}")
    sig = (mean - dk).astype(np.float32)
    k = _odd(kernel_size, "kernel_size")
    if method == "max":
        # odd reflection continues the edge slope, so the kernel sees a plausible field beyond
        # the image edge instead of a flat copy of it
        p = k
        big = np.pad(sig, p, mode="reflect", reflect_type="odd")
        el = cv2.getStructuringElement(cv2.MORPH_RECT, (k, k))
        closed = cv2.morphologyEx(big, cv2.MORPH_CLOSE, el, borderType=cv2.BORDER_REPLICATE)
        g = cv2.blur(closed, (k, k), borderType=cv2.BORDER_REPLICATE)[p:-p, p:-p]
    elif method == "mean":
        big = np.pad(sig, k, mode="reflect", reflect_type="odd")
        g = cv2.blur(big, (k, k), borderType=cv2.BORDER_REPLICATE)[k:-k, k:-k]
    elif method == "median":
        big = np.pad(sig, k, mode="reflect", reflect_type="odd")
        g = median_filter(big, size=k, mode="nearest")[k:-k, k:-k]
    else:
        g = fit_surface(sig, method=method, mask=mask, order=order, knot_spacing_px=knot_spacing_px)
    g = np.asarray(g, np.float32)
    g[~(g >= float(min_signal))] = 0.0
    return Flatfield(g, dk, method, k, n, None if kv is None else float(kv))


class FlatfieldLibrary:
    """Flatfields by tube voltage (the roll-off changes with kV; thesis §3.3).

    ``library[kv]`` returns the flatfield of that kV; :meth:`get` also accepts the nearest within
    ``tolerance_kv``.
    """

    def __init__(self, flatfields=()) -> None:
        self._by_kv: dict[float, Flatfield] = {}
        for f in flatfields:
            self.add(f)

    def add(self, flatfield: Flatfield) -> None:
        if not isinstance(flatfield, Flatfield) or flatfield.kv is None:
            raise ValueError("flatfield: expected a Flatfield with its kv set")
        self._by_kv[float(flatfield.kv)] = flatfield

    @property
    def kvs(self) -> list[float]:
        return sorted(self._by_kv)

    def __len__(self) -> int:
        return len(self._by_kv)

    def __getitem__(self, kv: float) -> Flatfield:
        return self.get(kv, tolerance_kv=0.0)

    def get(self, kv: float, *, tolerance_kv: float = 0.5) -> Flatfield:
        """The flatfield of the nearest kV within ``tolerance_kv``; ValueError names the kVs held."""
        if not self._by_kv:
            raise ValueError("kv: the flatfield library is empty")
        near = min(self._by_kv, key=lambda k: abs(k - float(kv)))
        if abs(near - float(kv)) > tolerance_kv:
            raise ValueError(f"kv: no flatfield for {kv} kV within {tolerance_kv} kV (have {self.kvs})")
        return self._by_kv[near]

    def to_dict(self, *, array_encoder=encode_array) -> dict:
        return {"type": "flatfield_library",
                "flatfields": [self._by_kv[k].to_dict(array_encoder=array_encoder) for k in self.kvs]}

    @classmethod
    def from_dict(cls, d: dict, *, array_decoder=decode_array) -> FlatfieldLibrary:
        return cls(Flatfield.from_dict(f, array_decoder=array_decoder) for f in d["flatfields"])
