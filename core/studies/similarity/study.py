"""Response study of the similarity metrics (thesis §6.3): noise, translation, rotation.

For a :class:`~core.studies.similarity.cases.RegistrationCase` (one bone, a reference pose, fluoroscope
ROIs of every view) and each metric of :data:`core.similarity.METRICS` (numpy references; a
pose's score is the mean over the views):

* **noise** — zero-mean Gaussian noise added to the flatfield-normalised fluoroscope ROIs at the
  reference pose, of standard deviation σ = level × the ROI's mean fluence (levels relative to
  the local signal, so that a foot behind soft tissue and a bare phantom compare); mean and SD
  over ``noise_repeats`` draws per level;
* **random perturbations** (n each, thesis: n = 1000) — translations of uniformly distributed
  length 0 … ``max_translation_px`` (converted to mm at the bone, random 3-D directions) and
  rotations of 0 … ``max_rotation_deg`` about random axes through the bone centre: the score
  against the displacement magnitude, binned means, Spearman rank correlation (a good metric
  falls monotonically: ρ near -1) and the fraction of displaced poses that score at least as high
  as the reference (false optima);
* **1-D sweeps** along the lab x, y, z translations (± ``max_translation_px``) and rotations
  about the lab x, y, z axes through the centre (± ``max_rotation_deg``): smoothness (number of
  interior local extrema), capture range (the distance from the reference over which the score
  falls monotonically on each side, within a tolerance of 0.5 % of the sweep's range; the
  smaller side is reported), position of the sweep's maximum, and peak sharpness (the curvature
  at the reference from a quadratic fit over ±2 samples, relative to the sweep's range).

:func:`summarize` condenses a study into one row per metric for ranking; :mod:`.study_report`
writes JSON and plots (``python -m core.studies.similarity.study_report``; figures
``resources/figures/similarity_*.png``).

Results and recommended default cost
------------------------------------
Run with the defaults (n = 1000 translations of 0–10 px and 1000 rotations of 0–10° per case,
41-sample sweeps, noise levels 0–0.5 of the mean fluence × 5 draws) on three ground-truth cases —
talus, calcaneus and second metatarsal of a :func:`core.synthetic.make_foot_scene` frame
(512 px, 0.40–0.41 mm per pixel at the bone, whole foot + soft tissue + walkway + beads in the
image, realistic noise/PSF/glare) — and on the real wrist sample. Means over the three bones
(``~1.5``: fluoroscope ROI smoothed with σ = 1.5 px; ρ: Spearman of score vs displacement;
"false": fraction of displaced poses scoring ≥ the truth; capture: monotonic range of the six
sweeps, max 10; offset: worst sweep maximum away from the truth; extrema: per sweep, 1 = unimodal):

==========  ========  ========  ==========  =========  ==========  ========  ========
metric      ρ trans   ρ rot     false t/r   capture    offset      extrema   @truth
                                (%)         px / deg   px / deg
==========  ========  ========  ==========  =========  ==========  ========  ========
gc~1.5      -0.82     -0.82     1.3 / 1.8   10 / 8.9   0 / 0.5     1.0       0.39
gc+go~1.5   -0.85     -0.85     1.8 / 2.2   10 / 10    0.5 / 1.5   1.0       0.42
gi~1.5      -0.85     -0.86     2.0 / 2.2   8.9 / 6.7  0.5 / 1.5   1.0       0.32
gc          -0.78     -0.80     1.4 / 1.1   9.4 / 9.1  0 / 0       1.4       0.25
gi          -0.84     -0.85     1.1 / 0.8   10 / 8.8   0 / 0.5     1.1       0.23
go          -0.86     -0.85     3.1 / 4.5   5.2 / 4.4  0.5 / 1.5   2.2       0.33
pi          -0.81     -0.85     0.7 / 0.5   10 / 10    0 / 0.5     1.0       0.10
rmi         -0.84     -0.78     2.2 / 1.6   8.7 / 7.6  0.5 / 0.5   1.2       0.09
ncc         -0.57     -0.66     15 / 10     2.9 / 2.1  8.5 / 10    5.7       0.36
mi          -0.48     -0.57     19 / 10     1.1 / 2.9  10 / 10     3.9       0.17
sid         -0.67     -0.52     5 / 15      1.6 / 1.7  1 / 10      9.9       0.004
lad         +0.25     +0.28     59 / 62     0 / 0      10 / 10     2.9       -0.77
==========  ========  ========  ==========  =========  ==========  ========  ========

* The gradient family (GC, GD, GI, GO), pattern intensity and regional MI fall monotonically
  with displacement and peak at the truth; NCC, MI/NMI, SID and LAD do not: with the whole foot in
  the image (overlapping bones, soft tissue) their maxima lie 8–10 px / 10° away and 10–19 % of
  displaced poses beat the truth (the thesis' cadaver phantoms had no soft tissue, which is why
  MI ranked well there; its finding that SID and LAD are flat is reproduced).
* Smoothing the fluoroscope ROI (σ = 1.5 px, done once per frame) makes every gradient metric
  unimodal along all sweeps and raises the score at the truth by ~0.1–0.2, at the cost of a
  broader peak (curvature at the truth 0.11 vs 0.21 per px², relative to the sweep range, for
  GC); it also keeps more of the score under added noise (at 0.1 × the mean fluence GC keeps 14 %
  of its truth score smoothed, loses it all unsmoothed). PI and GD collapse under added noise.
* Real data (wrist radius at the hand-found pose, no ground truth; 0.34 mm per DRR pixel): no
  metric has its optimum at the hand-found pose (a third to a half of the displaced poses score
  higher for the gradient metrics). The gradient metrics agree where it is instead: GC, GD, GI and
  GO, smoothed or not, peak at tx = -2.5 … -3.5 px, tz = +3 … +4.5 px (≈ 1.2 mm each),
  rx = +1.5 … +3° and rz = +2 … +2.5° from it; ty (along the shaft, which the image border cuts)
  and ry are not agreed on. NCC, MI, PI and RMI peak elsewhere or drift to the sweep ends.

**Recommended default cost: ``1 - GC`` on the σ = 1.5 px smoothed fluoroscope ROI** (Sobel
gradients, Ω = DRR > 0, the mean over both views): peak exactly at the truth in every sweep
(worst 0 px / 0.5°), unimodal sweeps, capture of the whole ±10 px and ~9° tested, 1–2 % false
optima, and the cheapest device metric (0.165 ms per 128 DRRs of 300² on an H100, one pass).
For a poor initial guess, ``1 - (GC + GO)/2`` (both smoothed) widens the rotational capture to
the full ±10° and is the most monotonic (ρ = -0.85), at ~5.7 × the device cost and a slightly
less exact peak (worst 1.5° in one sweep); the unsmoothed GC has a peak twice as sharp for a
final refinement.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.stats import spearmanr

from core.similarity.domain import line_integral_image
from core.similarity.metrics import METRICS
from core.studies.similarity.cases import RegistrationCase

__all__ = ["PARTS", "StudyConfig", "StudyResult", "combine", "curve_stats", "default_metrics", "merge",
           "response_study", "summarize"]

SWEEP_AXES = ("tx", "ty", "tz", "rx", "ry", "rz")


def default_metrics(smoothing_px: float = 1.5) -> dict[str, tuple[str, dict]]:
    """Every metric with its defaults, plus the gradient metrics on a fluoroscope ROI smoothed
    with a Gaussian of ``smoothing_px`` (named e.g. ``"gc~1.5"``)."""
    out = {k: (k, {}) for k in METRICS}
    for k in ("gd", "gc", "gi", "go"):
        out[f"{k}~{smoothing_px:g}"] = (k, {"fluoro_sigma": smoothing_px})
    return out


@dataclass(frozen=True)
class StudyConfig:
    """Parameters of :func:`response_study` (units in the names; defaults follow thesis §6.3).

    ``metrics`` maps a name to ``(kind, options)``: a key of :data:`METRICS` and its keyword
    options (default :func:`default_metrics`).
    """

    metrics: dict = field(default_factory=default_metrics)
    n_random: int = 1000
    max_translation_px: float = 10.0
    max_rotation_deg: float = 10.0
    sweep_steps: int = 41
    noise_levels: tuple[float, ...] = (0.0, 0.02, 0.05, 0.1, 0.2, 0.5)
    noise_repeats: int = 5
    bins: int = 5
    seed: int = 0

    def __post_init__(self) -> None:
        bad = [n for n, (k, _) in self.metrics.items() if k not in METRICS]
        if bad:
            raise ValueError(f"metrics: unknown kinds for {bad}; expected keys of METRICS")
        if self.n_random < 0 or self.sweep_steps < 5 or self.sweep_steps % 2 == 0:
            raise ValueError("n_random >= 0 and an odd sweep_steps >= 5 are required")


@dataclass(frozen=True, eq=False)
class StudyResult:
    """Raw results of one case (arrays keyed by metric kind)."""

    case: str
    truth: bool
    mm_per_px: float
    config: StudyConfig
    reference: dict[str, float]
    noise: dict[str, np.ndarray]  # name -> (n_levels, repeats)
    translation_px: np.ndarray  # (n,) displacement magnitudes
    translation: dict[str, np.ndarray]  # kind -> (n,)
    rotation_deg: np.ndarray
    rotation: dict[str, np.ndarray]
    sweep_offsets: dict[str, np.ndarray]  # axis -> (steps,) px or deg
    sweeps: dict[str, dict[str, np.ndarray]]  # kind -> axis -> (steps,)


def _scores(case: RegistrationCase, drrs: Sequence[np.ndarray], metrics: dict, fluoro=None) -> dict:
    """name -> (B,) mean over views of each pose's score."""
    fl = case.fluoro if fluoro is None else fluoro
    B = len(drrs[0])
    out = {}
    for name, (kind, opt) in metrics.items():
        f = METRICS[kind].function
        out[name] = np.array([np.mean([f(drrs[v][b], fl[v], **opt, **case.options(v))
                                       for v in range(len(fl))]) for b in range(B)])
    return out


def _evaluate(case: RegistrationCase, poses: np.ndarray, metrics: dict, chunk: int = 64) -> dict:
    parts = [_scores(case, case.drrs(poses[i : i + chunk]), metrics)
             for i in range(0, len(poses), chunk)]
    return {k: np.concatenate([p[k] for p in parts]) for k in metrics}


def _unit(rng: np.random.Generator, n: int) -> np.ndarray:
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def curve_stats(offsets: np.ndarray, scores: np.ndarray, *, tol: float = 0.005) -> dict:
    """Smoothness, capture range, peak position and sharpness of one 1-D sweep (see module docs).

    ``offsets`` must be symmetric about 0 with 0 in the middle; a score change smaller than
    ``tol`` × (max - min) counts as flat.
    """
    s = np.asarray(scores, dtype=float)
    x = np.asarray(offsets, dtype=float)
    c = len(s) // 2
    rng = float(s.max() - s.min())
    eps = tol * rng
    d = np.diff(s)
    sig = np.where(np.abs(d) <= eps, 0, np.sign(d))
    nz = sig[sig != 0]
    extrema = int(np.sum(nz[1:] != nz[:-1])) if nz.size > 1 else 0

    def side(idx) -> float:
        reach = 0.0
        for a, b in itertools.pairwise(idx):
            if s[b] > s[a] + eps:
                break
            reach = abs(x[b])
        return reach

    lo = side(list(range(c, -1, -1)))
    hi = side(list(range(c, len(s))))
    sharp = 0.0
    if rng > 0:
        sl = slice(c - 2, c + 3)
        a = np.polyfit(x[sl] - x[c], s[sl], 2)[0]
        sharp = float(-2 * a / rng)
    return {"local_extrema": extrema, "capture_lo": lo, "capture_hi": hi, "capture": min(lo, hi),
            "peak_offset": float(x[int(np.argmax(s))]), "sharpness": sharp, "range": rng}


PARTS = ("noise", "translation", "rotation", "sweeps")


def response_study(case: RegistrationCase, config: StudyConfig | None = None, *,
                   parts: Sequence[str] = PARTS,
                   progress: Callable[[str], None] | None = None) -> StudyResult:
    """Run the noise, random-perturbation and sweep experiments on ``case``.

    ``parts`` selects experiments (each draws from its own random stream, so a study split over
    processes and joined with :func:`merge` equals one run whole).
    """
    cfg = config or StudyConfig()
    bad = [p for p in parts if p not in PARTS]
    if bad:
        raise ValueError(f"parts: expected a subset of {PARTS}, got {bad}")
    say = progress or (lambda msg: None)
    mets = cfg.metrics
    ref = {k: float(v[0]) for k, v in _evaluate(case, case.pose[None], mets).items()}
    noise: dict = {}
    tpx, trans, rdeg, rot = np.zeros(0), {}, np.zeros(0), {}
    offsets: dict = {}
    sweeps: dict = {k: {} for k in mets}

    if "noise" in parts:
        say(f"{case.name}: noise")
        rng = np.random.default_rng([cfg.seed, 0])
        ref_drrs = case.drrs(case.pose[None])
        noise = {k: np.zeros((len(cfg.noise_levels), cfg.noise_repeats)) for k in mets}
        for i, lev in enumerate(cfg.noise_levels):
            for j in range(cfg.noise_repeats):
                fl = [line_integral_image(np.clip(f + rng.normal(0, lev * f.mean(), f.shape), 0, 1))
                      for f in case.fluence]
                for k, v in _scores(case, ref_drrs, mets, fluoro=fl).items():
                    noise[k][i, j] = v[0]
    if "translation" in parts:
        say(f"{case.name}: {cfg.n_random} translations")
        rng = np.random.default_rng([cfg.seed, 1])
        tpx = rng.uniform(0, cfg.max_translation_px, cfg.n_random)
        poses = case.perturb(_unit(rng, cfg.n_random) * (tpx * case.mm_per_px)[:, None])
        trans = _evaluate(case, poses, mets)
    if "rotation" in parts:
        say(f"{case.name}: {cfg.n_random} rotations")
        rng = np.random.default_rng([cfg.seed, 2])
        rdeg = rng.uniform(0, cfg.max_rotation_deg, cfg.n_random)
        poses = case.perturb(np.zeros((cfg.n_random, 3)),
                             _unit(rng, cfg.n_random) * np.deg2rad(rdeg)[:, None])
        rot = _evaluate(case, poses, mets)
    if "sweeps" in parts:
        say(f"{case.name}: sweeps")
        for a, axis in enumerate(SWEEP_AXES):
            rot_axis = a >= 3
            top = cfg.max_rotation_deg if rot_axis else cfg.max_translation_px
            off = np.linspace(-top, top, cfg.sweep_steps)
            vec = np.zeros((len(off), 3))
            vec[:, a % 3] = np.deg2rad(off) if rot_axis else off * case.mm_per_px
            poses = case.perturb(np.zeros_like(vec), vec) if rot_axis else case.perturb(vec)
            offsets[axis] = off
            for k, v in _evaluate(case, poses, mets).items():
                sweeps[k][axis] = v
    return StudyResult(case.name, case.truth, case.mm_per_px, cfg, ref, noise, tpx, trans, rdeg, rot,
                       offsets, sweeps)


def merge(parts: Sequence[StudyResult]) -> StudyResult:
    """Join partial results of one case (from :func:`response_study` with different ``parts``)."""
    if not parts or len({p.case for p in parts}) != 1:
        raise ValueError("parts: expected partial results of one case")
    first = parts[0]
    noise, trans, rot, offsets = {}, {}, {}, {}
    sweeps: dict = {k: {} for k in first.reference}
    tpx, rdeg = np.zeros(0), np.zeros(0)
    for p in parts:
        noise.update(p.noise)
        if p.translation:
            trans, tpx = p.translation, p.translation_px
        if p.rotation:
            rot, rdeg = p.rotation, p.rotation_deg
        offsets.update(p.sweep_offsets)
        for k, v in p.sweeps.items():
            sweeps[k].update(v)
    return StudyResult(first.case, first.truth, first.mm_per_px, first.config, first.reference, noise,
                       tpx, trans, rdeg, rot, offsets, sweeps)


def _perturbation_stats(mag: np.ndarray, score: np.ndarray, ref: float, top: float, bins: int) -> dict:
    edges = np.linspace(0, top, bins + 1)
    idx = np.clip(np.digitize(mag, edges) - 1, 0, bins - 1)
    means = [float(score[idx == i].mean()) if np.any(idx == i) else float("nan") for i in range(bins)]
    sds = [float(score[idx == i].std()) if np.any(idx == i) else float("nan") for i in range(bins)]
    rho = float(spearmanr(mag, score).statistic) if np.ptp(score) > 0 else 0.0
    return {"bin_edges": edges.tolist(), "mean": means, "sd": sds, "spearman": rho,
            "false_optimum_fraction": float(np.mean(score >= ref))}


def combine(result: StudyResult, weights: dict[str, float], name: str) -> StudyResult:
    """A new result with one more 'metric' ``name``: the weighted mean of existing ones."""
    w = {k: float(v) for k, v in weights.items()}
    tot = sum(w.values())

    def mix(d):
        return sum(w[k] * d[k] for k in w) / tot

    sweeps = dict(result.sweeps)
    sweeps[name] = {a: mix({k: result.sweeps[k][a] for k in w}) for a in result.sweep_offsets}
    ref = dict(result.reference)
    ref[name] = mix(result.reference)
    return StudyResult(result.case, result.truth, result.mm_per_px, result.config, ref,
                       {**result.noise, name: mix(result.noise)}, result.translation_px,
                       {**result.translation, name: mix(result.translation)}, result.rotation_deg,
                       {**result.rotation, name: mix(result.rotation)}, result.sweep_offsets, sweeps)


def summarize(result: StudyResult) -> dict:
    """Per metric: reference score, noise response, perturbation and sweep statistics."""
    cfg = result.config
    out = {}
    for kind in result.reference:
        ref = result.reference[kind]
        nz = result.noise[kind].mean(axis=1)
        sw = {a: curve_stats(result.sweep_offsets[a], result.sweeps[kind][a]) for a in result.sweep_offsets}
        t_axes = [sw[a] for a in SWEEP_AXES[:3]]
        r_axes = [sw[a] for a in SWEEP_AXES[3:]]
        out[kind] = {
            "reference": ref,
            "noise_mean": nz.tolist(),
            "noise_retained_at_0.1": float(np.interp(0.1, cfg.noise_levels, nz) / nz[0]) if nz[0] else 0.0,
            "translation": _perturbation_stats(result.translation_px, result.translation[kind], ref,
                                               cfg.max_translation_px, cfg.bins),
            "rotation": _perturbation_stats(result.rotation_deg, result.rotation[kind], ref,
                                            cfg.max_rotation_deg, cfg.bins),
            "sweeps": sw,
            "sweep_local_extrema_mean": float(np.mean([s["local_extrema"] for s in sw.values()])),
            "capture_translation_px_mean": float(np.mean([s["capture"] for s in t_axes])),
            "capture_rotation_deg_mean": float(np.mean([s["capture"] for s in r_axes])),
            "peak_offset_translation_px_max": float(max(abs(s["peak_offset"]) for s in t_axes)),
            "peak_offset_rotation_deg_max": float(max(abs(s["peak_offset"]) for s in r_axes)),
            "sharpness_translation_mean": float(np.mean([s["sharpness"] for s in t_axes])),
        }
    return out
