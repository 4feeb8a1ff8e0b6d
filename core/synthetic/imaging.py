"""Image formation of an image-intensifier fluoroscope, from line integrals to 12-bit frames.

Chain (each stage switchable; order follows the physics of an X-ray image intensifier + camera)
------------------------------------------------------------------------------------------------
1. **Attenuation** (Beer–Lambert, thesis eq. 2.1): relative fluence ``I/I0 = exp(-∫μ dl)``.
   Monoenergetic: scatter, beam hardening and the heel effect are left out (thesis §2.1 accepts
   the same simplification).
2. **Quantum noise**: the input phosphor absorbs a Poisson number of X-ray quanta with mean
   ``photons_per_pixel · I/I0``; the signal is rescaled so full fluence reads 1. Absorption is the
   quantum sink of the chain, so the noise enters *before* any blur.
3. **Blur** (thesis §3.4.2): input-phosphor light spread, electron optics and the lens give a
   compact PSF — a Gaussian of ``psf_sigma_px`` or a supplied kernel (e.g. a measured pinhole
   PSF) — plus optional *veiling glare*, a fraction ``glare_fraction`` of the light spread by a
   wide Gaussian. Kernels are normalised, so blur preserves the image sum.
4. **Brightness roll-off** (vignetting, thesis §3.3): ``g(r) = 1 / (1 + a² r²)²`` (the cos⁴ law
   of a lens at field angle ``atan(a r)``), with ``a`` set so that ``g(1) = rolloff_edge``,
   ``r`` = distance from the image centre / half the shorter image side.
5. **Spatial distortion** (thesis §3.5): pincushion + S-twist of the intensifier,
   :class:`~core.synthetic.distortion.Distortion`, applied with ``cv2.remap`` (bilinear); stages
   1–4 therefore live in *ideal* (pinhole) pixel coordinates, where the PSF is shift-invariant.
   An optional circular ``aperture_radius`` (same normalised ``r`` about the distortion centre, or
   the image centre) blacks out the region outside the intensifier's round field.
6. **Camera**: ``DN = dark_dn + gain_dn · signal + N(0, read_noise_dn²)``, rounded and clipped to
   ``[0, 2**bits - 1]`` (12 bits: 0..4095, the Phantom v5.2's range), returned as ``uint16``.

The dataclass defaults switch every degradation *off* (noise-free, sharp, flat, undistorted,
12-bit): :meth:`ImagingModel.fluoroscope` gives the realistic, documented set for a camera.
:meth:`ImagingModel.to_float` is the ground-truth flatfield correction ``(DN - dark) /
(flat - dark)`` clipped to [0, 1], the float image the rest of Talus works with (DESIGN.md).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import cv2
import numpy as np

from .._validate import as_float_array, positive
from ..geometry.camera import Camera
from .distortion import Distortion

__all__ = ["ImagingModel", "gaussian_blur", "quantum_noise", "rolloff_gain"]


def _rng(rng) -> np.random.Generator:
    if isinstance(rng, np.random.Generator):
        return rng
    if rng is None:
        raise ValueError("rng: a numpy Generator or an int seed is needed when noise is switched on")
    return np.random.default_rng(rng)


def quantum_noise(relative_fluence: np.ndarray, photons_per_pixel: float, rng) -> np.ndarray:
    """Poisson-sampled detected quanta, rescaled so the mean equals ``relative_fluence``.

    The variance of the result is ``relative_fluence / photons_per_pixel`` (variance = mean in
    counts).
    """
    n0 = positive(photons_per_pixel, "photons_per_pixel")
    lam = np.clip(np.asarray(relative_fluence, dtype=np.float64), 0.0, None) * n0
    return _rng(rng).poisson(lam).astype(np.float64) / n0


def gaussian_blur(image: np.ndarray, sigma_px: float) -> np.ndarray:
    """Normalised Gaussian blur (reflecting borders preserve the sum exactly).

    Very wide kernels (σ > 16 px, veiling glare) are applied on a box-downsampled copy and
    interpolated back, which keeps the sum to a fraction of a per cent.
    """
    img = np.asarray(image, dtype=np.float64)
    if sigma_px <= 0:
        return img.copy()
    f = int(sigma_px // 8) if sigma_px > 16 else 1
    if f <= 1:
        return cv2.GaussianBlur(img, (0, 0), sigmaX=float(sigma_px), borderType=cv2.BORDER_REFLECT)
    h, w = img.shape
    small = cv2.resize(img, (max(1, w // f), max(1, h // f)), interpolation=cv2.INTER_AREA)
    small = cv2.GaussianBlur(small, (0, 0), sigmaX=float(sigma_px) / f, borderType=cv2.BORDER_REFLECT)
    return cv2.resize(small, (w, h), interpolation=cv2.INTER_LINEAR)


def _convolve(image: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    k = np.asarray(kernel, dtype=np.float64)
    k = k / k.sum()
    return cv2.filter2D(np.asarray(image, dtype=np.float64), -1, k[::-1, ::-1],
                        borderType=cv2.BORDER_REFLECT)


def rolloff_gain(shape: tuple[int, int], edge_ratio: float, center=None) -> np.ndarray:
    """``(h, w)`` cos⁴-law brightness gain: 1 at ``center`` (default image centre), ``edge_ratio``
    at half the shorter side from it."""
    e = float(edge_ratio)
    if not 0 < e <= 1:
        raise ValueError(f"rolloff_edge: expected a centre-to-edge ratio in (0, 1], got {edge_ratio}")
    h, w = shape
    cu, cv = ((w - 1) / 2, (h - 1) / 2) if center is None else center
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    r2 = ((u - cu) ** 2 + (v - cv) ** 2) / (min(h, w) / 2) ** 2
    a2 = e**-0.5 - 1.0
    return 1.0 / (1.0 + a2 * r2) ** 2


@dataclass(frozen=True, eq=False)
class ImagingModel:
    """Every stage of the fluoroscope image chain (module docs give the physics and order).

    Parameters
    ----------
    photons_per_pixel : float or None
        Mean detected X-ray quanta per pixel at full fluence; ``None`` = no quantum noise.
    psf_sigma_px : float
        Gaussian PSF σ in pixels (0 = sharp); ignored when ``psf_kernel`` is given.
    psf_kernel : (k, k) array or None
        Odd-sized PSF kernel (normalised internally).
    glare_fraction, glare_sigma_px : float
        Fraction of light in the wide veiling-glare Gaussian and its σ in pixels.
    rolloff_edge : float
        Brightness at the image edge relative to the centre (1 = no roll-off).
    distortion : Distortion or None
    aperture_radius : float or None
        Radius of the round intensifier field in units of half the shorter image side.
    gain_dn, dark_dn, read_noise_dn : float
        Camera DN at full fluence (above dark), dark offset and read noise σ, in DN.
    bits : int
        Camera bit depth (12 → 0..4095).
    """

    photons_per_pixel: float | None = None
    psf_sigma_px: float = 0.0
    psf_kernel: np.ndarray | None = None
    glare_fraction: float = 0.0
    glare_sigma_px: float = 50.0
    rolloff_edge: float = 1.0
    distortion: Distortion | None = None
    aperture_radius: float | None = None
    gain_dn: float = 3200.0
    dark_dn: float = 60.0
    read_noise_dn: float = 0.0
    bits: int = 12

    def __post_init__(self) -> None:
        if self.photons_per_pixel is not None:
            positive(self.photons_per_pixel, "photons_per_pixel")
        if not (np.isfinite(self.psf_sigma_px) and self.psf_sigma_px >= 0):
            raise ValueError(f"psf_sigma_px: expected a sigma >= 0 in pixels, got {self.psf_sigma_px}")
        if self.psf_kernel is not None:
            k = as_float_array(self.psf_kernel, "psf_kernel", ndim=2)
            if k.shape[0] % 2 == 0 or k.shape[1] % 2 == 0 or np.any(k < 0) or k.sum() <= 0:
                raise ValueError(f"psf_kernel: expected an odd-sized non-negative kernel with a "
                                 f"positive sum, got shape {k.shape}")
            object.__setattr__(self, "psf_kernel", k)
        if not 0 <= self.glare_fraction < 1:
            raise ValueError(f"glare_fraction: expected a fraction in [0, 1), got {self.glare_fraction}")
        positive(self.glare_sigma_px, "glare_sigma_px")
        if not 0 < self.rolloff_edge <= 1:
            raise ValueError(f"rolloff_edge: expected a ratio in (0, 1], got {self.rolloff_edge}")
        if self.distortion is not None and not isinstance(self.distortion, Distortion):
            raise ValueError("distortion: expected a Distortion or None")
        if self.aperture_radius is not None:
            positive(self.aperture_radius, "aperture_radius")
        positive(self.gain_dn, "gain_dn")
        if self.dark_dn < 0 or self.read_noise_dn < 0:
            raise ValueError("dark_dn, read_noise_dn: expected values >= 0 (DN)")
        if int(self.bits) != self.bits or not 1 <= self.bits <= 16:
            raise ValueError(f"bits: expected an integer bit depth in 1..16, got {self.bits}")
        if self.dark_dn + self.gain_dn > 2**self.bits - 1:
            raise ValueError(f"gain_dn + dark_dn = {self.gain_dn + self.dark_dn} saturates a "
                             f"{self.bits}-bit camera at full fluence")

    # ------------------------------------------------------------------ realistic preset
    @classmethod
    def fluoroscope(
        cls,
        camera: Camera,
        *,
        rng: np.random.Generator | int = 0,
        fluence_per_mm2: float = 5000.0,
        mtf50_cycles_per_mm: float = 0.5,
        glare_fraction: float = 0.05,
        glare_sigma_mm: float = 20.0,
        rolloff_edge: float = 0.65,
        distortion: Distortion | str | None = "random",
        aperture_radius: float | None = None,
        gain_dn: float = 3200.0,
        dark_dn: float = 60.0,
        read_noise_dn: float = 3.0,
    ) -> ImagingModel:
        """A realistic model for ``camera`` with parameters in physical units.

        * ``fluence_per_mm2`` (detected quanta/mm² at full fluence, ×pixel area → per pixel):
          the lab's tube at ~19 mA (thesis §3.2) gives ~0.04 mAs per 2 ms frame; at ~15–25 µGy/mAs
          at 1.4 m that is ~0.6–1 µGy at the intensifier, ~3×10⁴ quanta/(mm²·µGy) for a 70 kV
          spectrum (IEC 62220-1 RQA5) → 2–3×10⁴ quanta/mm²; CsI absorption (~0.6) and the
          lens-coupled high-speed camera (a secondary quantum sink) leave an effective
          ~5×10³/mm², ~430 quanta per 0.29 mm pixel in air and a few tens behind the hindfoot:
          the noisy raw frames of thesis §3.
        * ``mtf50_cycles_per_mm``: the lab's measured MTF50 ≈ 0.5 cycles/mm (thesis §3.4.1,
          Fig. 3.7); a Gaussian PSF has MTF50 = sqrt(ln 2 / 2π²) / σ → σ ≈ 0.37 mm.
        * ``glare_fraction`` / ``glare_sigma_mm``: veiling glare of intensifiers, a few per cent
          of the light spread over centimetres.
        * ``rolloff_edge``: 0.65 — the strong edge darkening of thesis Fig. 3.4.
        * ``distortion``: ``"random"`` draws :meth:`Distortion.random` from ``rng`` (each view
          differs, as each intensifier sits differently in the Earth's field); or a Distortion;
          or None.
        * camera: 3200 DN at full fluence over a 60 DN dark level, 3 DN read noise, 12 bits.
        """
        if camera.pixel_size is None:
            raise ValueError("camera: needs pixel_size to convert mm parameters to pixels")
        px = camera.pixel_size
        g = np.random.default_rng(rng) if not isinstance(rng, np.random.Generator) else rng
        if isinstance(distortion, str):
            if distortion != "random":
                raise ValueError(f"distortion: expected 'random', a Distortion or None, got {distortion!r}")
            distortion = Distortion.random(camera, g)
        sigma_mm = np.sqrt(np.log(2) / (2 * np.pi**2)) / positive(mtf50_cycles_per_mm, "mtf50_cycles_per_mm")
        return cls(
            photons_per_pixel=positive(fluence_per_mm2, "fluence_per_mm2") * px * px,
            psf_sigma_px=sigma_mm / px,
            glare_fraction=glare_fraction,
            glare_sigma_px=positive(glare_sigma_mm, "glare_sigma_mm") / px,
            rolloff_edge=rolloff_edge,
            distortion=distortion,
            aperture_radius=aperture_radius,
            gain_dn=gain_dn,
            dark_dn=dark_dn,
            read_noise_dn=read_noise_dn,
        )

    # ------------------------------------------------------------------ stages
    def blur(self, signal: np.ndarray) -> np.ndarray:
        """Stage 3: PSF (Gaussian or kernel) plus veiling glare; preserves the sum."""
        out = (_convolve(signal, self.psf_kernel) if self.psf_kernel is not None
               else gaussian_blur(signal, self.psf_sigma_px))
        if self.glare_fraction > 0:
            out = (1 - self.glare_fraction) * out + self.glare_fraction * gaussian_blur(
                signal, self.glare_sigma_px)
        return out

    def _optics(self, signal: np.ndarray) -> np.ndarray:
        """Stages 3–5 on a relative-fluence image (noise-free part of the chain)."""
        s = self.blur(signal)
        if self.rolloff_edge < 1:
            s = s * rolloff_gain(s.shape, self.rolloff_edge)
        if self.distortion is not None:
            s = self.distortion.warp(s)
        if self.aperture_radius is not None:
            h, w = s.shape
            c = self.distortion.center if self.distortion is not None else ((w - 1) / 2, (h - 1) / 2)
            v, u = np.mgrid[0:h, 0:w]
            r = np.hypot(u - c[0], v - c[1]) / (min(h, w) / 2)
            s = np.where(r <= self.aperture_radius, s, 0.0)
        return s

    def _check(self, line_integral) -> np.ndarray:
        L = as_float_array(line_integral, "line_integral", ndim=2)
        return L

    def expected_signal(self, line_integral) -> np.ndarray:
        """Noise-free signal (1 = full fluence at the centre) after stages 1, 3, 4, 5; float64."""
        return self._optics(np.exp(-self._check(line_integral)))

    def expected_dn(self, line_integral) -> np.ndarray:
        """Noise-free, unquantised camera output (DN, float64) for a line-integral image."""
        return self.dark_dn + self.gain_dn * self.expected_signal(line_integral)

    def flatfield(self, shape: tuple[int, int]) -> np.ndarray:
        """Noise-free empty-field frame ``I0`` in DN (float64): the flatfield ground truth."""
        return self.expected_dn(np.zeros(shape))

    def apply(self, line_integral, *, rng=None) -> np.ndarray:
        """Run the whole chain on a ``(H, W)`` line-integral image; returns a ``uint16`` frame.

        ``rng`` (Generator or int seed) drives the quantum and read noise; it may be omitted only
        when both are switched off.
        """
        L = self._check(line_integral)
        noisy = self.photons_per_pixel is not None or self.read_noise_dn > 0
        g = _rng(rng) if noisy else None
        s = np.exp(-L)
        if self.photons_per_pixel is not None:
            s = quantum_noise(s, self.photons_per_pixel, g)
        dn = self.dark_dn + self.gain_dn * self._optics(s)
        if self.read_noise_dn > 0:
            dn = dn + g.normal(0.0, self.read_noise_dn, size=dn.shape)
        return np.clip(np.rint(dn), 0, 2**self.bits - 1).astype(np.uint16)

    def to_float(self, image, *, flatfield: np.ndarray | None = None) -> np.ndarray:
        """Flatfield-normalised float32 image in [0, 1]: ``(DN - dark) / (I0 - dark)``.

        ``flatfield`` defaults to the model's noise-free :meth:`flatfield` (ground truth);
        pixels with no signal in the flatfield (outside the aperture) map to 0.
        """
        img = np.asarray(image, dtype=np.float64)
        if img.ndim != 2:
            raise ValueError(f"image: expected a 2-D frame, got shape {img.shape}")
        flat = self.flatfield(img.shape) if flatfield is None else np.asarray(flatfield, float)
        den = flat - self.dark_dn
        ok = den > 1e-6 * self.gain_dn
        out = np.where(ok, (img - self.dark_dn) / np.where(ok, den, 1.0), 0.0)
        return np.clip(out, 0.0, 1.0).astype(np.float32)

    def to_dict(self) -> dict:
        """JSON-ready description of every stage."""
        d = asdict(self)
        d["psf_kernel"] = None if self.psf_kernel is None else self.psf_kernel.tolist()
        d["distortion"] = None if self.distortion is None else self.distortion.to_dict()
        d["order"] = ["beer-lambert", "quantum-noise", "psf+glare", "rolloff", "distortion",
                      "aperture", "camera-gain-dark-readnoise", "quantise"]
        return d
