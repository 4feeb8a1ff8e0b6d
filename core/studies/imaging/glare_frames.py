"""Veiling glare measured the way a lab's calibration does, on a synthetic view: frames of a lead
disc on the intensifier face and empty-field frames through the view's imaging model, flatfield-
normalised and undistorted, then :func:`core.imaging.glare.estimate_glare` (used by
:mod:`core.studies.imaging.glare_study` and the tracking trial,
:class:`core.studies.tracking.acceptance.TrackingScene` with ``glare``). The imaging model's own
glare values are never read here.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

__all__ = ["disc_line_integrals", "measure_glare"]


def disc_line_integrals(cam, diameter_mm: float = 60.0, thickness_mm: float = 2.0) -> np.ndarray:
    """Line integrals of a lead disc on ``cam``'s intensifier face, in the middle of the field."""
    from core.render.attenuation import attenuation_per_mm
    from core.synthetic.analytic import cylinder_line_integrals
    from core.synthetic.calib_objects import face_frame

    return cylinder_line_integrals(cam, face_frame(cam, thickness_mm=thickness_mm), diameter_mm / 2,
                                   thickness_mm / 2, attenuation_per_mm("lead", 60.0), supersample=3,
                                   average="fluence")


def measure_glare(cam, model, unwarp, *, n_disc: int = 4, n_flat: int = 10, seed: int = 0):
    """The glare of one view measured from rendered calibration frames (module docs)."""
    import cv2

    from core.imaging.glare import estimate_glare

    g = np.random.default_rng([seed, 0x61A2E])
    L = disc_line_integrals(cam)
    dark = np.mean([np.rint(model.dark_dn + g.normal(0, model.read_noise_dn, L.shape)) for _ in range(4)], 0)
    disc = np.mean([model.apply(L, rng=g) for _ in range(n_disc)], axis=0) - dark
    flat = np.mean([model.apply(np.zeros_like(L), rng=g) for _ in range(n_flat)], axis=0) - dark
    field = flat > 0.5 * np.percentile(flat, 99)
    img = unwarp(np.where(field, disc / np.where(field, flat, 1.0), 0.0).astype(np.float32))
    inside = unwarp(field.astype(np.float32)) > 0.99
    inside = cv2.erode(inside.astype(np.uint8), np.ones((25, 25), np.uint8))
    return replace(estimate_glare(img, mask=inside.astype(bool)), n_frames=n_disc)
