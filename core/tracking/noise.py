"""The noise correction of the gradient correlation of magnitudes: its option, the frame's
estimate of its quantum noise and the noise maps of the host cost.

:data:`NOISE_OPTION` is the ``gc`` term's option (set by
:class:`core.tracking.register.RegistrationOptions`'s ``noise_correction``); :class:`FrameNoise`
gives :class:`core.tracking.cost.FrameImages` its per-view ``E₁`` estimate (drawn from the frame,
kept for its later registrations; :class:`core.tracking.feed.FrameFeed` draws the next frame's
samples ahead); :func:`noise_maps` turns it into the host cost's per-pixel maps. The Gauss–Newton
engine's device form is :meth:`core.tracking.engine.GaussNewtonCost._noise_setup`. All of them
are importable from :mod:`core.tracking.cost` as before.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["NOISE_OPTION", "FrameNoise", "noise_maps"]

#: the ``gc`` term's option of the noise correction (:func:`noise_maps`; set by
#: :class:`core.tracking.register.RegistrationOptions`'s ``noise_correction``)
NOISE_OPTION = "noise_correction"


def noise_maps(frame: FrameNoise, views, regions, fluoro_sigma: float, operator: str = "sobel") -> list:
    """Per view the expected squared gradient magnitude of the noise over a full-resolution search
    region, ``E₁ / F_s``: ``E₁`` estimated from the frame
    (:meth:`core.tracking.cost.FrameImages.noise_energy`),
    ``F_s = exp(-G_σ ∗ y)`` the fluence of the region's line integrals ``y`` (``regions``, before
    any neighbour is subtracted) smoothed as the metric smooths the fluoroscope (``fluoro_sigma``
    px, truncated at 4σ, borders replicated). The Gauss–Newton engine computes the same on the
    device (:func:`core.tracking.engine_kernels.fluoro_gradient_kernel`)."""
    from ..similarity.batched import _smooth

    out = []
    for v, y in zip(views, regions, strict=True):
        e1 = frame.noise_energy(v, fluoro_sigma, operator)
        ys = _smooth(y, fluoro_sigma)
        out.append(e1 * np.exp(ys))
    return out


class FrameNoise:
    """The noise-estimate part of :class:`core.tracking.cost.FrameImages`: uses its ``_fluence``,
    ``_given`` (masks), ``_valid`` (valid range) and ``_noise`` (a dict, set in its ``__init__``)."""

    _fluence: tuple
    _given: tuple
    _valid: tuple | None
    _noise: dict
    n_views: int

    def noise_energy(self, view: int, fluoro_sigma: float = 0.0, operator: str = "sobel") -> float:
        """``E₁`` of ``view``: the expected squared gradient magnitude of its quantum noise at full
        fluence after the metric's smoothing (``fluoro_sigma`` px) and ``operator``, estimated from
        this frame (:func:`core.similarity.gradient.frame_noise_energy`: patches about the
        brightest points of a lattice of the usable pixels, sampled once per view and patch size);
        kept per view, operator and σ (to 1 %) for the frame's later registrations."""
        from ..similarity.gradient import _patch_radius, noise_energy_of_samples

        s = float(fluoro_sigma)
        key = (int(view), operator, round(math.log(s) / 0.01) if s > 0 else None)
        hit = self._noise.get(key)
        if hit is None:
            hit = self._noise[key] = noise_energy_of_samples(self._noise_samples(int(view), _patch_radius(s)),
                                                             fluoro_sigma=s, operator=operator)
        return hit

    def _noise_samples(self, view: int, radius: int) -> np.ndarray:
        from ..similarity.gradient import noise_samples

        P = self._noise.get((view, radius))
        if P is None:
            P = self._noise[(view, radius)] = noise_samples(self._fluence[view], radius=radius,
                                                            mask=self._given[view], valid_range=self._valid)
        return P

    @property
    def noise_sample_keys(self) -> tuple[tuple[int, int], ...]:
        """The ``(view, patch radius)`` of the noise samples drawn so far (:meth:`noise_energy`)."""
        return tuple(k for k in list(self._noise) if len(k) == 2)

    def prepare_noise(self, keys) -> None:
        """Draw the noise samples of these ``(view, patch radius)`` now (those a frame before this
        one used: :class:`core.tracking.feed.FrameFeed` draws them in its worker thread while
        that frame registers), so that :meth:`noise_energy` finds them; the same values as when
        drawn at its call."""
        for v, r in keys:
            if 0 <= int(v) < self.n_views and int(r) >= 1:
                self._noise_samples(int(v), int(r))
