"""Result types of bead localisation: estimates, uncertainties and failure reasons.

Pixel convention (Talus-wide): ``(u, v) = (column, row)``, origin at the centre of the top-left
pixel; image arrays are indexed ``[row, col]``.

Every estimate comes with a status code. :data:`STATUS_NAMES` lists them; code 0 is success and
every other code is a flagged failure whose coordinates are NaN — a localizer never returns a
silent wrong centroid for the cases it can recognise (guess outside the image, bead touching the
border, flat patch without a bead, a fit or iteration that diverged).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["STATUS", "STATUS_NAMES", "Localization"]

#: Status codes of a localisation (index into this tuple).
STATUS_NAMES: tuple[str, ...] = (
    "ok",  # 0
    "outside",  # 1: the initial guess lies outside the image
    "border",  # 2: the bead's window reaches past the image border
    "flat",  # 3: no bead signal above the noise in the window (flat patch)
    "diverged",  # 4: the estimate left the search window or did not converge
    "bad_fit",  # 5: the model fit is degenerate (singular system, width out of range)
    "invalid",  # 6: the guess itself is not finite (NaN) — used for missing beads
)
#: Name → code.
STATUS: dict[str, int] = {name: i for i, name in enumerate(STATUS_NAMES)}


@dataclass(frozen=True, eq=False)
class Localization:
    """Sub-pixel bead centres with uncertainties and failure flags.

    All arrays share the leading shape ``S`` of the guesses (e.g. ``(N,)`` beads, or
    ``(F, N)`` frames × beads).

    Attributes
    ----------
    uv : (*S, 2) float64
        Estimated centres ``(u, v) = (column, row)`` in pixels (origin at the centre of the
        top-left pixel); NaN where ``status != 0``.
    sigma : (*S, 2) float64
        One-standard-deviation uncertainty of ``u`` and ``v`` in pixels (NaN where unknown
        or failed). For the recommended localizer this is the least-squares covariance corrected
        for the measured noise correlation; for the thesis algorithms it is a first-order
        propagation of the pixel noise through the estimator's weights.
    status : (*S,) int8
        Codes of :data:`STATUS_NAMES` (0 = ok).
    contrast : (*S,) float64
        Bead contrast (background minus bead, in image units, positive for a detected bead).
    snr : (*S,) float64
        Contrast divided by the pixel noise estimated in the window.
    iterations : (*S,) int32
        Iterations used (1 for one-shot methods).
    method : str
        Name of the localizer.
    """

    uv: np.ndarray
    sigma: np.ndarray
    status: np.ndarray
    contrast: np.ndarray
    snr: np.ndarray
    iterations: np.ndarray
    method: str

    @property
    def ok(self) -> np.ndarray:
        """Boolean mask of successful estimates."""
        return self.status == 0

    @property
    def shape(self) -> tuple[int, ...]:
        return self.status.shape

    def reasons(self) -> np.ndarray:
        """Array (same shape as ``status``) of the status names, e.g. ``"ok"``, ``"border"``."""
        return np.asarray(STATUS_NAMES, dtype=object)[self.status]

    def counts(self) -> dict[str, int]:
        """How many estimates ended with each status (only the ones that occur)."""
        codes, n = np.unique(self.status, return_counts=True)
        return {STATUS_NAMES[int(c)]: int(k) for c, k in zip(codes, n, strict=True)}

    def reshape(self, *shape: int) -> Localization:
        """The same result with leading shape ``shape``."""
        return Localization(
            uv=self.uv.reshape(*shape, 2),
            sigma=self.sigma.reshape(*shape, 2),
            status=self.status.reshape(shape),
            contrast=self.contrast.reshape(shape),
            snr=self.snr.reshape(shape),
            iterations=self.iterations.reshape(shape),
            method=self.method,
        )

    @classmethod
    def empty(cls, n: int, method: str) -> Localization:
        """``n`` failed (``"invalid"``) estimates, filled in by the localizers."""
        return cls(
            uv=np.full((n, 2), np.nan),
            sigma=np.full((n, 2), np.nan),
            status=np.full(n, STATUS["invalid"], dtype=np.int8),
            contrast=np.full(n, np.nan),
            snr=np.full(n, np.nan),
            iterations=np.zeros(n, dtype=np.int32),
            method=method,
        )
