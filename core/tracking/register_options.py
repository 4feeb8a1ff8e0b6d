"""The options of :func:`core.tracking.register.register`: the pyramid levels (:class:`Level`, the
default levels of each search :func:`default_levels`) and :class:`RegistrationOptions` with their
checks. Re-exported by :mod:`core.tracking.register`, whose module docs describe the searches and
the final stage they choose.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace

import numpy as np

from .cost import DEFAULT_TERMS, NOISE_OPTION, MetricTerm

__all__ = ["COARSE_NEWTON_MM", "COARSE_NEWTON_STEP_PX", "FINAL_STEP", "STAGE_SEARCH_TOL", "Level",
           "RegistrationOptions", "before_stage", "default_levels", "newton_step"]

_METHODS = ("cmaes", "pso", "pattern", "quadratic", "nelder_mead", "powell", "gauss_newton")
_SEARCHES = ("global", "local", "newton", "global_newton")
_FINALS = (None, "likelihood")
_FINAL_CONFIDENCES = ("sandwich", "sandwich+move", "independent")
#: Design half-widths (mm, degrees) of the full-resolution quadratic fits.
FINAL_STEP = (0.25, 0.5)
#: Full-resolution pixels coarser than this (mm at the bone) are *coarse* for the Gauss–Newton
#: search (:func:`newton_step`): 256² views of a foot (about 0.8 mm at the bone) and coarser, not
#: 512² (0.4 mm) or 1024² (0.2 mm).
COARSE_NEWTON_MM = 0.6
#: The Gauss–Newton search's translation half-step on coarse pixels, in pixels (rotation: twice
#: that in degrees, the ratio of :data:`FINAL_STEP`).
COARSE_NEWTON_STEP_PX = 0.45
#: With a final stage after it (``final`` of :class:`RegistrationOptions`), the ``"newton"`` search's
#: full-resolution Gauss–Newton level stops once every coordinate of its next step is below this (mm,
#: degrees) instead of its own ``tol_x`` (0.02): the stage refines the pose by its own cost, so the
#: similarity's search only needs to land inside the stage's basin, not converge to its own optimum
#: (:func:`before_stage`). None: the search as without a stage. First frames and retries (the
#: ``"global_newton"`` search) and the restart check keep their levels (joint tracking's second round
#: in a first frame is a ``"newton"`` search from round 0's poses: it stops at this tolerance too). The
#: step that ends the search is taken without rendering it: the stage starts at ``x + d`` and the
#: similarity's score there is its last model's. Acceptance trial at 512², 1 mm
#: voxels, 20 frames, three bones jointly with the stage (this 2-core x86_64 machine's CPU;
#: :mod:`core.studies.tracking.stage_search`): the search's 13-pose steps per bone-frame after the first
#: 2.51 (its own 0.02) → 1.61 (0.25) → 1.14 (0.5), the stage's 2.96-2.98 either way, × the Cramér–Rao
#: bound (mm/°) tibia 1.81/1.28 → 1.80/1.29 → 1.81/1.22, talus 1.54/1.66 → 1.55/1.66 → 1.52/1.63,
#: calcaneus 1.30/1.63 → 1.28/1.60 → 1.27/1.55, no frame over 4× the bound, every frame converged.
#: One NVIDIA H100, ``talus bench track`` (1024², 100 frames): one bone with the stage 9.15 → 7.16 ms a
#: frame after the first, three bones jointly 23.37 → 20.35 ms, bound ratios the same or lower
#: (``resources/benchmarks/tracking_bench_stage_search_h100.json``; README, Tracking: accuracy and speed).
STAGE_SEARCH_TOL: float | None = 0.5


def newton_step(mm_per_px: float) -> tuple[tuple[float, float], dict]:
    """The Gauss–Newton search's central-difference half-steps (mm, degrees) and search options
    (:func:`~core.tracking.engine_search.gauss_newton_search`) at full-resolution pixels of
    ``mm_per_px`` (mm at the bone).

    Up to :data:`COARSE_NEWTON_MM`: :data:`FINAL_STEP` and no options (the moments' gradient,
    over the centre DRR's domain). Coarser: half-steps of :data:`COARSE_NEWTON_STEP_PX` pixels
    (at least :data:`FINAL_STEP`; rounded to 0.01 mm) and ``gradient="corrected"`` — the moments'
    gradient plus the mean, over the search's steps, of the 13 scores' central differences less
    it (each pose scored over its own domain, as the cost is). On coarse pixels the domain's
    edge (the DRR's support, in whole pixels) is a large share of its pixels, and the moments'
    gradient, which holds the centre's domain fixed, misses its change: on the harder trial at
    192² (talus, frame 2, from 0.5 mm / 1° off; this 2-core CPU machine) the moments' search
    stopped at cost 0.7037, 0.27 mm / 0.62° off the truth, where the scores' differences still
    pointed to the quadratic-model search's 0.6974 (0.03 mm / 0.22°); their difference from the
    moments' gradient was about the same at half-steps of 0.25, 0.5 and 1 mm and along the way.
    The scores' differences alone are too noisy at a quarter-pixel and biased by the cost's
    asymmetry at wider half-steps (ideal 128² views: 0.05-0.13 mm, 0.08-0.21° off at 0.6 pixel,
    against 0.001 mm with the moments).
    """
    if not (np.isfinite(mm_per_px) and mm_per_px > 0):
        raise ValueError(f"mm_per_px: expected a positive pixel size, got {mm_per_px!r}")
    if mm_per_px <= COARSE_NEWTON_MM:
        return FINAL_STEP, {}
    t = max(FINAL_STEP[0], round(COARSE_NEWTON_STEP_PX * mm_per_px, 2))
    return (t, round(t * FINAL_STEP[1] / FINAL_STEP[0], 2)), {"gradient": "corrected"}


def before_stage(level: Level, options: RegistrationOptions) -> Level:
    """``level`` as the ``"newton"`` search runs it in a registration of ``options``: with a final
    stage (``options.final``) and :data:`STAGE_SEARCH_TOL` set, a full-resolution Gauss–Newton
    level stops at that looser tolerance (its ``tol_x`` the larger of the two); otherwise
    ``level`` itself."""
    tol = STAGE_SEARCH_TOL
    if (options.final is None or tol is None or level.method != "gauss_newton"
            or level.scale != options.final_scale or level.tol_x >= tol):
        return level
    return replace(level, tol_x=float(tol))


@dataclass(frozen=True)
class Level:
    """One pyramid level: ``scale`` (full-resolution pixels per DRR pixel), the optimiser
    (``method`` in ``cmaes``, ``pso``, ``pattern``, ``quadratic``, ``nelder_mead``, ``powell``),
    its initial step ``sigma`` (mm, degrees; CMA-ES σ, pattern/simplex step, quadratic design
    half-widths; PSO uses ±3·sigma as its start range), ``popsize`` (CMA-ES; PSO particles),
    ``max_generations``, ``tol_x`` (mm/degrees) and extra optimiser keywords ``options``
    (for ``quadratic``: ``min_step`` as (mm, degrees), ``kind``, ``trust``)."""

    scale: float = 1.0
    method: str = "cmaes"
    sigma: tuple[float, float] = (1.0, 1.0)
    popsize: int | None = None
    max_generations: int = 60
    tol_x: float = 0.01
    options: Mapping = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.method not in _METHODS:
            raise ValueError(f"method: expected one of {_METHODS}, got {self.method!r}")
        if not (np.isfinite(self.scale) and self.scale > 0):
            raise ValueError(f"scale: expected a positive pyramid scale, got {self.scale!r}")
        if len(self.sigma) != 2 or min(self.sigma) <= 0:
            raise ValueError(f"sigma: expected (mm, degrees) > 0, got {self.sigma!r}")
        object.__setattr__(self, "options", dict(self.options))

    def to_dict(self) -> dict:
        return {"scale": self.scale, "method": self.method, "sigma": list(self.sigma),
                "popsize": self.popsize, "max_generations": self.max_generations,
                "tol_x": self.tol_x, "options": dict(self.options)}


def default_levels(mm_per_px: float, *, sigma: tuple[float, float] = (1.5, 1.5),
                   coarsest_mm: float = 1.2, search: str = "global") -> tuple[Level, ...]:
    """Levels from DRR pixels of about ``coarsest_mm`` mm down to full resolution.

    Pyramid scales 4, 2, 1 are kept while ``scale × mm_per_px <= coarsest_mm`` (1024² views of a
    foot, ~0.3 mm pixels: 4, 2, 1; 256²: 1 only).

    * ``"global"``: CMA-ES (population 24, first step ``sigma`` in mm and degrees) at the
      coarsest scale, then quadratic-model searches at each finer scale (at a single scale:
      CMA-ES then a quadratic search, both at full resolution);
    * ``"local"``: a quadratic search at the second-finest scale (design half-widths
      ``max(sigma / 2, (0.4 mm, 0.8°))``) and one at full resolution; with one scale, one
      search from ``(0.5 mm, 1°)`` down to :data:`FINAL_STEP`;
    * ``"global_newton"``: the CMA-ES stage of ``"global"``, then Gauss–Newton steps at each finer
      scale (half-steps :data:`FINAL_STEP` × scale) — the widened options of ``"newton"``;
    * ``"newton"``: Gauss–Newton steps at full resolution only (central-difference half-steps
      :data:`FINAL_STEP`, at most 8, stopping below 0.02 or when the predicted decrease is
      below a tenth of the cost's roughness); when they do not converge (a move beyond their
      reach), :func:`~core.tracking.register.register` starts again at half resolution with twice
      the half-steps. On pixels coarser than :data:`COARSE_NEWTON_MM` the full-resolution
      Gauss–Newton levels (here and in ``"global_newton"``) take :func:`newton_step`'s wider
      half-steps and the scores' gradient.

    The full-resolution search ends with designs of :data:`FINAL_STEP` half-widths and a Newton
    step below 0.02 (mm, degrees).
    """
    if not (np.isfinite(mm_per_px) and mm_per_px > 0):
        raise ValueError(f"mm_per_px: expected a positive pixel size, got {mm_per_px!r}")
    if search not in _SEARCHES:
        raise ValueError(f"search: expected one of {_SEARCHES}, got {search!r}")
    if len(sigma) != 2 or min(sigma) <= 0:
        raise ValueError(f"sigma: expected (mm, degrees) > 0, got {sigma!r}")
    scales = [s for s in (4.0, 2.0) if s * mm_per_px <= coarsest_mm] + [1.0]
    fin = FINAL_STEP
    mid = (max(sigma[0] / 2, 0.4), max(sigma[1] / 2, 0.8))

    def final(step):
        return Level(scale=1.0, method="quadratic", sigma=step, max_generations=8, tol_x=0.02,
                     options={"min_step": fin})

    def between(s):
        return Level(scale=s, method="quadratic", sigma=mid, max_generations=6, tol_x=0.1,
                     options={"min_step": mid})

    gn_step, gn_options = newton_step(mm_per_px)
    if search == "newton":  # a coarse level first made it slower, not more accurate (1024² trial)
        return (Level(scale=1.0, method="gauss_newton", sigma=gn_step, max_generations=8, tol_x=0.02,
                      options=gn_options),)
    if search == "global_newton":  # CMA-ES at the coarsest scale, then Gauss-Newton steps
        out = [Level(scale=scales[0], method="cmaes", sigma=tuple(sigma), popsize=24,
                     max_generations=40, tol_x=0.05)]
        out += [Level(scale=s, method="gauss_newton", sigma=(fin[0] * s, fin[1] * s), max_generations=6,
                      tol_x=0.05) for s in scales[1:-1]]
        out.append(Level(scale=1.0, method="gauss_newton", sigma=gn_step, max_generations=8, tol_x=0.02,
                         options=gn_options))
        return tuple(out)
    if search == "global":
        out = [Level(scale=scales[0], method="cmaes", sigma=tuple(sigma), popsize=24,
                     max_generations=40, tol_x=0.05)]
        out += [between(s) for s in scales[1:-1]]
        out.append(final((0.5, 1.0)))
        return tuple(out)
    if len(scales) > 1:
        return between(scales[-2]), final(fin)
    return (final((0.5, 1.0)),)


@dataclass(frozen=True)
class RegistrationOptions:
    """Options of :func:`core.tracking.register.register`.

    ``levels=None`` picks :func:`default_levels` (with ``search`` and ``sigma``) for the pixel
    size at the bone. ``bounds``: search box half-widths about the initial pose (mm, degrees).
    ``refine``: an extra local method run at full resolution after the levels (``"pattern"``,
    ``"quadratic"``, ``"nelder_mead"``, ``"powell"`` or None) with initial step ``refine_step``
    (mm, degrees). ``margin_px``: extra ROI margin. ``final_scale``: the pyramid scale that
    counts as full resolution — the finest automatic level, the final score, the refinement and
    the confidence fit (2 for detectors much finer than the bone needs, e.g. 1760² views of a
    wrist at 0.15 mm per pixel). ``final``: ``"likelihood"`` ends the registration with the
    weighted least-squares refinement of :func:`core.tracking.final_stage.final_stage`
    (high-pass σ ``final_highpass_px`` pixels, at most ``final_iters`` steps, taken when it
    moves the pose by at most ``final_reach`` (mm, degrees); ``final_lag_px``: the lag window
    of its covariance, None for the engine's default; ``final_confidence``: the frame's
    covariance — ``"sandwich"`` (the residual's autocorrelation accounted for),
    ``"sandwich+move"`` (the default: plus the outer product of the stage's move from the
    similarity's optimum, the two costs' disagreement as a systematic part; on the 1024² trial,
    one H200, the talus's errors were within 2σ on 94 % of the axes, against 85-86 % with the
    sandwich alone) or ``"independent"``; ``final_others_gain``: the neighbours' DRRs fitted with
    a gain of their own instead of subtracted as they are), or None. ``noise_correction``: the
    gradient correlation of the magnitudes takes the quantum noise's expected share out of the
    fluoroscope's squared gradients at full resolution (debiased magnitudes
    ``sqrt(max(|g|² - E₁/F, 0))``, ``E₁`` estimated from each frame:
    :meth:`core.tracking.cost.FrameImages.noise_energy`), on the Gauss–Newton engine and the host
    cost alike; it sets the ``gc`` terms' ``noise_correction`` option (not those of the
    components' form, which noise does not bias this way).
    """

    terms: tuple[MetricTerm, ...] = DEFAULT_TERMS
    levels: tuple[Level, ...] | None = None
    bounds: tuple[float, float] = (10.0, 10.0)
    sigma: tuple[float, float] = (1.5, 1.5)
    search: str = "global"
    final_scale: float = 1.0
    refine: str | None = None
    refine_step: tuple[float, float] = (0.1, 0.1)
    refine_tol: float = 0.005
    margin_px: int = 4
    seed: int = 0
    final: str | None = None
    final_highpass_px: float = 4.0
    final_iters: int = 5
    final_reach: tuple[float, float] = (1.0, 2.0)
    final_lag_px: int | None = None
    final_confidence: str = "sandwich+move"
    final_others_gain: bool = False
    noise_correction: bool = False

    def __post_init__(self) -> None:
        if not isinstance(self.noise_correction, bool):
            raise ValueError(f"noise_correction: expected True or False, got {self.noise_correction!r}")
        # the gc terms of the magnitudes carry the correction's option (the costs and the engine
        # read it there); this flag sets or clears it
        terms = []
        for t in self.terms:
            if t.kind == "gc" and not t.options.get("components", False):
                opts = {k: v for k, v in t.options.items() if k != NOISE_OPTION}
                if self.noise_correction:
                    opts[NOISE_OPTION] = True
                if opts != dict(t.options):
                    t = replace(t, options=opts)
            terms.append(t)
        object.__setattr__(self, "terms", tuple(terms))
        if self.levels is not None:
            object.__setattr__(self, "levels", tuple(self.levels))
            if not self.levels or not all(isinstance(lv, Level) for lv in self.levels):
                raise ValueError("levels: expected a non-empty sequence of Level (or None for automatic)")
        if len(self.bounds) != 2 or min(self.bounds) <= 0:
            raise ValueError(f"bounds: expected (mm, degrees) > 0, got {self.bounds!r}")
        if self.refine not in (None, "pattern", "quadratic", "nelder_mead", "powell"):
            raise ValueError(f"refine: expected 'pattern', 'quadratic', 'nelder_mead', 'powell' or None, "
                             f"got {self.refine!r}")
        if self.search not in _SEARCHES:
            raise ValueError(f"search: expected one of {_SEARCHES}, got {self.search!r}")
        if not (np.isfinite(self.final_scale) and self.final_scale >= 1):
            raise ValueError(f"final_scale: expected a pyramid scale >= 1, got {self.final_scale!r}")
        if self.final not in _FINALS:
            raise ValueError(f"final: expected one of {_FINALS}, got {self.final!r}")
        if not (np.isfinite(self.final_highpass_px) and self.final_highpass_px >= 0):
            raise ValueError(f"final_highpass_px: expected a σ >= 0 (pixels), got {self.final_highpass_px!r}")
        fi = self.final_iters
        if isinstance(fi, bool) or int(fi) != fi or fi < 1:
            raise ValueError(f"final_iters: expected an integer >= 1, got {self.final_iters!r}")
        if len(self.final_reach) != 2 or not all(np.isfinite(v) and v > 0 for v in self.final_reach):
            raise ValueError(f"final_reach: expected (mm, degrees) > 0, got {self.final_reach!r}")
        lag = self.final_lag_px
        if lag is not None and (isinstance(lag, bool) or int(lag) != lag or lag < 0):
            raise ValueError(f"final_lag_px: expected an integer >= 0 or None, got {lag!r}")
        if not isinstance(self.final_others_gain, bool):
            raise ValueError(f"final_others_gain: expected True or False, got {self.final_others_gain!r}")
        if self.final_confidence not in _FINAL_CONFIDENCES:
            raise ValueError(f"final_confidence: expected one of {_FINAL_CONFIDENCES}, "
                             f"got {self.final_confidence!r}")

    def widened(self, factor: float = 2.0) -> RegistrationOptions:
        """The same options with ``factor``× larger bounds and first steps, twice the
        population and a global first stage (for a retry after a failure or a poor initial
        guess): ``"global"``, or ``"global_newton"`` (CMA-ES, then Gauss–Newton steps) for the
        Gauss–Newton searches."""
        lv = None
        if self.levels is not None:
            lv = tuple(replace(x, sigma=(x.sigma[0] * factor, x.sigma[1] * factor),
                               popsize=None if x.popsize is None else 2 * x.popsize) if i == 0 else x
                       for i, x in enumerate(self.levels))
        return replace(self, bounds=(self.bounds[0] * factor, self.bounds[1] * factor),
                       sigma=(self.sigma[0] * factor, self.sigma[1] * factor), levels=lv,
                       search="global_newton" if self.search in ("newton", "global_newton") else "global",
                       seed=self.seed + 1)

    def to_dict(self) -> dict:
        return {"terms": [t.to_dict() for t in self.terms],
                "levels": None if self.levels is None else [lv.to_dict() for lv in self.levels],
                "bounds": list(self.bounds), "sigma": list(self.sigma), "search": self.search,
                "final_scale": self.final_scale,
                "refine": self.refine,
                "refine_step": list(self.refine_step), "refine_tol": self.refine_tol,
                "margin_px": self.margin_px, "seed": self.seed, "final": self.final,
                "final_highpass_px": self.final_highpass_px, "final_iters": self.final_iters,
                "final_reach": list(self.final_reach), "final_lag_px": self.final_lag_px,
                "final_confidence": self.final_confidence, "final_others_gain": self.final_others_gain,
                "noise_correction": self.noise_correction}
