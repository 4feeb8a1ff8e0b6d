"""The likelihood final stage's settings and records (:mod:`core.tracking.final_stage`, whose
module docs say what each setting does and what it measured): the model of the region's pixels
(:class:`FinalModel`, per-bone overrides :class:`BoneStage`), the refinement's confidence as a
registration result's fit (:class:`LikelihoodFit`), and a result with the stage's move taken back
(:func:`rejected`). :mod:`core.tracking.final_stage` re-exports every name."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

__all__ = ["BoneStage", "FinalModel", "LikelihoodFit", "rejected"]


@dataclass(frozen=True)
class BoneStage:
    """One bone's overrides of the stage's settings (:attr:`FinalModel.bones`): ``highpass_px``
    the high-pass σ of that bone's stage (pixels; 0: none) instead of the registration options'
    ``final_highpass_px`` (None: theirs); ``tissue`` False: that bone's stage fits no tissue
    regressor (the model's :attr:`~FinalModel.tissue` volumes still follow the bone's pose in the
    other bones' stages); ``rim_sigmas`` that bone's band at the round field's rim instead of the
    model's :attr:`~FinalModel.rim_sigmas` (None: the model's; 0: none)."""

    highpass_px: float | None = None
    tissue: bool = True
    rim_sigmas: float | None = None

    def __post_init__(self) -> None:
        hp = self.highpass_px
        if hp is not None and not (np.isfinite(hp) and hp >= 0):
            raise ValueError(f"highpass_px: expected None or a σ >= 0 (pixels), got {hp!r}")
        if not isinstance(self.tissue, bool | np.bool_):
            raise ValueError(f"tissue: expected True or False, got {self.tissue!r}")
        object.__setattr__(self, "tissue", bool(self.tissue))
        if hp is not None:
            object.__setattr__(self, "highpass_px", float(hp))
        rs = self.rim_sigmas
        if rs is not None:
            if not (np.isfinite(rs) and rs >= 0):
                raise ValueError(f"rim_sigmas: expected None or a width >= 0 (σ), got {rs!r}")
            object.__setattr__(self, "rim_sigmas", float(rs))

    def to_dict(self) -> dict:
        d = {"highpass_px": self.highpass_px, "tissue": self.tissue}
        if self.rim_sigmas is not None:
            d["rim_sigmas"] = self.rim_sigmas
        return d


@dataclass(frozen=True)
class FinalModel:
    """Which pixels of the region count and how much (:mod:`core.tracking.final_stage`'s docs).
    ``FinalModel(robust=None)`` is the stage as first measured: every usable pixel of the search
    region, weighted by its expected counts."""

    support_px: float | None = None
    robust: float | None = 2.5
    robust_sigma_px: float = 2.0
    robust_kind: str = "cauchy"
    rounds: int = 1
    #: soft-tissue volumes ``(CTVolume, bone)`` (HU or 1/mm), each following the pose of bone
    #: ``bone`` of the registration's renderer: rendered at the current estimate of that pose and
    #: filtered as the bone's DRRs, an extra regressor with a gain of its own (final_stage's
    #: docs: Soft tissue)
    tissue: tuple = field(default=(), compare=False)
    #: each tissue volume its own regressor (gain) instead of their sum one
    tissue_each: bool = False
    #: the PSF (an odd 2-D kernel estimated from calibration images, never a generator's) the
    #: tissue's line integrals are blurred by as fluence, ``-log(psf ∗ exp(-L))``; None: none
    tissue_psf: object = field(default=None, compare=False)
    #: the tissue rendered again at the first refinement's poses before the robust rounds (the
    #: stage's own bone moved; the neighbours' poses stay those it was given)
    tissue_again: bool = False
    #: per-bone overrides ``{bone: BoneStage}`` (bone indices of the registration's renderer, as
    #: :attr:`tissue`'s; a dict of ``BoneStage`` or of its keyword dicts; kept as sorted pairs):
    #: that bone's high-pass σ and whether its stage fits the tissue (:meth:`for_bone`)
    bones: tuple = ()
    #: usable pixels within ``rim_sigmas`` σ of the stage's high-pass of an unusable one (the
    #: round field's rim) weighted 0 (:mod:`core.tracking.likelihood_rim`); None: none
    rim_sigmas: float | None = None

    def __post_init__(self) -> None:
        if self.support_px is not None and not (np.isfinite(self.support_px) and self.support_px >= 0):
            raise ValueError(f"support_px: expected None or a size >= 0 (pixels), got {self.support_px!r}")
        if self.robust is not None and not (np.isfinite(self.robust) and self.robust > 0):
            raise ValueError(f"robust: expected None or a threshold > 0, got {self.robust!r}")
        if self.robust_kind not in ("cauchy", "huber"):
            raise ValueError(f"robust_kind: expected 'cauchy' or 'huber', got {self.robust_kind!r}")
        if not (np.isfinite(self.robust_sigma_px) and self.robust_sigma_px > 0):
            raise ValueError(f"robust_sigma_px: expected a σ > 0 (pixels), got {self.robust_sigma_px!r}")
        if self.rim_sigmas is not None and not (np.isfinite(self.rim_sigmas) and self.rim_sigmas > 0):
            raise ValueError(f"rim_sigmas: expected None or a width > 0 (σ), got {self.rim_sigmas!r}")
        if int(self.rounds) != self.rounds or self.rounds < 1:
            raise ValueError(f"rounds: expected an integer >= 1, got {self.rounds!r}")
        from ..render.volume import CTVolume

        t = tuple((v, int(b)) for v, b in self.tissue)
        if not all(isinstance(v, CTVolume) and b >= 0 for v, b in t):
            raise ValueError("tissue: expected (CTVolume, bone index >= 0) pairs")
        object.__setattr__(self, "tissue", t)
        items = self.bones.items() if isinstance(self.bones, dict) else self.bones
        per = {}
        for b, st in items:
            if isinstance(b, str) and b.isdigit():  # to_dict's keys
                b = int(b)
            if int(b) != b or b < 0:
                raise ValueError(f"bones: expected bone indices >= 0, got {b!r}")
            if isinstance(st, dict):
                st = BoneStage(**st)
            if not isinstance(st, BoneStage):
                raise ValueError(f"bones: expected BoneStage (or its keyword dict) per bone, got {st!r}")
            per[int(b)] = st
        object.__setattr__(self, "bones", tuple(sorted(per.items())))

    def for_bone(self, bone: int, highpass_px: float) -> tuple[FinalModel, float]:
        """``(model, highpass_px)`` of bone ``bone``'s stage: this model without its tissue where
        the bone's :class:`BoneStage` turns it off, with its band at the rim, and its high-pass σ
        (``highpass_px``, the registration options', where it gives none). A bone without
        overrides: ``(self, highpass_px)`` unchanged."""
        st = dict(self.bones).get(int(bone))
        if st is None:
            return self, highpass_px
        m = self if st.tissue or not self.tissue else replace(self, tissue=())
        if st.rim_sigmas is not None and (st.rim_sigmas or None) != m.rim_sigmas:
            m = replace(m, rim_sigmas=st.rim_sigmas or None)
        return m, (highpass_px if st.highpass_px is None else st.highpass_px)

    def to_dict(self) -> dict:
        d = {"support_px": self.support_px, "robust": self.robust, "robust_sigma_px": self.robust_sigma_px,
             "robust_kind": self.robust_kind, "rounds": self.rounds}
        if self.tissue:
            d["tissue"] = [{"name": v.name, "bone": b, "spacing_mm": v.spacing.tolist()}
                           for v, b in self.tissue]
            d["tissue_each"] = self.tissue_each
            d["tissue_psf"] = None if self.tissue_psf is None else list(np.shape(self.tissue_psf))
            d["tissue_again"] = self.tissue_again
        if self.bones:
            d["bones"] = {str(b): st.to_dict() for b, st in self.bones}
        if self.rim_sigmas is not None:
            d["rim_sigmas"] = self.rim_sigmas
        return d


@dataclass(frozen=True, eq=False)
class LikelihoodFit:
    """The refinement's confidence in the form :func:`core.tracking.confidence.confidence_from_fit`
    reads (``Σ = 2 · noise · H⁻¹``): ``H = 2 Σ⁻¹`` and ``noise = 1`` give back ``covariance``, the
    stage's covariance (mm, degrees; ``final_confidence`` of the options, from
    :meth:`core.tracking.engine_likelihood.LikelihoodEngine.refine`); ``x`` the refined
    parameters, ``chi2`` the weighted residual, ``covariance_independent`` the covariance that
    treats the pixels as independent (for comparison); ``similarity`` the registration result the
    stage started from (the similarity's optimum), which :func:`rejected` gives back."""

    H: np.ndarray
    noise: float
    covariance: np.ndarray
    x: np.ndarray
    chi2: float
    covariance_independent: np.ndarray
    method: str = "likelihood"
    similarity: object = None

    @classmethod
    def of(cls, covariance, *, x, chi2: float, covariance_independent, similarity=None) -> LikelihoodFit:
        C = np.asarray(covariance, dtype=float)
        return cls(2.0 * np.linalg.inv(C), 1.0, C, np.asarray(x, dtype=float), float(chi2),
                   np.asarray(covariance_independent, dtype=float), similarity=similarity)


def rejected(res):
    """``res`` (a registration result whose pose is the final stage's) with the similarity's pose
    back — the stage's move rejected — or None where its pose is not the stage's (not taken, or
    changed since). Pose, ``x``, score and view scores are the similarity's; the work, the time and
    the stage's outcome in ``timing`` stay (``likelihood_taken`` 0, ``likelihood_rejected`` 1, its
    move kept), and so does the fit: the stage's covariance plus its move (``"sandwich+move"``)
    spans the two poses, so the confidence computed from it still holds."""
    fit = getattr(res, "fit", None)
    prior = getattr(fit, "similarity", None)
    if prior is None or not (res.timing or {}).get("likelihood_taken"):
        return None
    timing = {**res.timing, "likelihood_taken": 0, "likelihood_rejected": 1}
    return replace(res, pose=prior.pose, x=prior.x, score=prior.score, view_scores=prior.view_scores,
                   timing=timing)
