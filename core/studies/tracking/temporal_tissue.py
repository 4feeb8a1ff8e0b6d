"""The soft tissue taken from the previous frames' residual (``python -m
core.studies.tracking.temporal_tissue``).

The likelihood final stage (:mod:`core.tracking.final_stage`) high-passes the DRRs and the line
integrals by 4 px (1024²; 1 px at 256²) to take out the soft tissue's line integral, which throws
away the bone's low frequencies (:mod:`core.studies.tracking.stage_limits`); no smooth background
replaces it (:mod:`core.studies.tracking.background_fit`) and a CT tissue volume as a regressor
helps the translations only under a wider high-pass (:mod:`core.studies.tracking.tissue_regressor`).
Here the tissue — with the walkway and the model's mismatch at bone and skin edges, everything
the bones' DRRs do not explain and that moves slowly — is taken from the frames before: the
residual of frame ``t - k`` (:func:`residual_images`: its line integrals minus the three bones'
DRRs at their poses, a gain per bone and view fitted on the high-passed images) averaged over
``k = 1 … K`` (:func:`averaged`; optionally each shifted by the refined bone's projected motion
and low-passed), then either subtracted from frame ``t``'s line integrals or given to the fit as
one more regressor with its own gain, and the same weighted least-squares refinement
(:class:`core.tracking.likelihood_cost.LikelihoodCost`, the stage's robust factors and second
refinement) run with a narrower high-pass or none.

Variants (:func:`parse`): ``<source><K>[l[σ]][s][g][c][t]:<method>`` — ``source`` ``a`` (oracle:
the other frames' residuals at the TRUE poses, the upper limit of the idea), ``b`` (realistic,
causal: at the poses the same variant estimated in those frames, run frame after frame from the
trial's start, the first ``K`` frames refined by today's form — the feedback of a pose error
included), ``p`` (realistic, two passes: at the poses today's form ``hp4+r`` estimated in those
frames) or ``q`` (three passes: at the poses the ``p`` form estimated in those frames); ``K``
frames before ``t`` (``c``, centred: also the ``K`` after it — offline, the bones' motion cancels
to first order); ``l``: the averaged residual low-passed by a Gaussian of σ px at
1024² scaled (default 4, i.e. 1 px at 256²); ``s``: each residual shifted by the bone's projected
centroid motion; ``g``: the residual a regressor with its own gain instead of subtracted at gain
1; ``t`` (probe, ``a`` only): the soft tissue's true change since each frame added back (what is
left is the bones' edges' mismatch moving); ``method`` as
:func:`core.studies.tracking.background_fit.method` (``hp<σ>`` a high-pass of σ px at 1024²
scaled, ``hp0`` none; ``leg<k>`` a Legendre background; ``+r`` the robust second refinement).
A plain method (``hp4+r``, today's form) uses no residual. The residuals' bone gains are 1 (the
frame's bones are at gain 1 in line integrals; ``residual_gain_hp``: fitted on high-passed images
instead — they come out 0.6–0.93 at 256², the frame's blur), and the neighbours' DRRs subtracted
with them (:func:`neighbour_correction`).

Frames (:mod:`core.studies.tracking.background_fit`): ``grid`` (the distortion correction fitted
to grid frames, the user's path) and ``true`` (the true residual warp removed, oracle); the
veiling glare measured from disc frames and undone. Each frame noise-free (the error there is the
*bias*) and with ``seeds`` noise draws of the trial's chain (the previous frames' residuals from
the same draw index, independent noise; deviations from the noise-free estimate: the *spread*).
Every refinement starts from the bone's estimated pose (:func:`core.studies.tracking.
tissue_regressor.estimated_poses`, 0.05 mm / 0.05° per axis off the truth), the other bones at
theirs subtracted at gain 1. Ratios are over the Cramér–Rao bound of the evaluated frames. Only
this study reads the truth.

Measured (``resources/benchmarks/tracking_temporal_tissue_cpu.json``, this 2-core x86_64 machine,
shared; 256², 1 mm voxels, the 20-frame trial — the 100-frame trial's motion per frame — frames 4,
8, 12, 16, each noise-free and with 2 draws: 8 samples per bone, a spread ratio ±25 %; RMS error
over the bound, mm / degrees, tibia, talus, calcaneus; today's form ``hp4+r`` 1.74/0.91,
1.47/2.29, 1.66/1.67 on ``true`` and 2.98/0.99, 1.38/2.17, 2.21/1.60 on ``grid`` frames):

* The previous frames fail even at the TRUE poses (``true``): ``a1:hp0+r`` 4.36/3.40, 4.46/3.34,
  5.03/1.25 (bias 4.12/2.92, 3.98/2.15, 4.60/0.94 against today's 0.97/0.26, 0.29/0.35,
  0.53/0.35); K = 2 and 4 worse (``a4:hp0+r`` bias 7.76/6.69, 11.0/5.10, 9.82/2.83), a low-pass
  does not help (``a4l:hp0+r`` alike), a high-pass makes it worse (``a1:hp4+r`` tibia bias 13.1,
  ``a1:hp2+r`` 14.8), so does a shift by the bone's motion (``a1s:hp2+r`` 4.13/1.70, 2.09/1.93,
  2.40/2.00); with the tissue's true change added back (``a1t:hp0+r``) the tibia is still biased
  4.2× (the bones' edges). Why: the bones move 0.17–1.47 px per frame here (the view's largest
  centroid motion), and the residual's change from frame t-1 to t over the stage's regions is
  0.005–0.065 RMS in line integral (noise-free; the bone's own peak 0.37–0.81), on the bone's scale.
* Centred (the frame before and the frame after, offline) at the TRUE poses it beats today's form:
  ``a1c:hp0+r`` 0.74/1.14, 1.05/1.13, 1.37/1.21 on ``true`` and 0.72/1.11, 1.04/1.20, 1.40/1.16 on
  ``grid`` (there bias 0.45/0.33, 0.35/0.50, 0.28/0.23: the grid's leftover distortion is in the
  residual too); only the tibia's rotation is not better (1.14 and 1.11 against 0.91 and 0.99,
  within the ratios' ±25 %). The change left is 0.0024–0.011 RMS.
  K = 2 (``a2c``) biases more, the low-pass (``a1cl``) and a 0.5 px high-pass (``a1c:hp2+r``,
  tibia 4.2×) lose.
* At a tracker's poses it does not: the residuals at today's form's poses (two passes,
  ``p1c:hp0+r``) 1.29/1.08, 1.57/1.97, 1.30/1.42 (``true``) and 2.24/1.00, 1.54/1.78, 1.59/1.43
  (``grid``): a pose error δ at t±1 leaves -δ·∂D in their residual, which pulls frame t to the same
  error, so a bias constant over three frames is a fixed point (``grid`` tibia mean error (+0.030,
  -0.016, +0.006) mm in the first pass, (+0.029, -0.016, +0.003) in the second; calcaneus (0.022,
  0.023, 0.020) → (0.017, 0.020, 0.016)); the talus's translation is worse than today's on both
  sets. A third pass (``q1c:hp0+r``, the residuals at the second pass's poses) lowers the spread
  (talus 1.37/1.69 → 0.99/1.31 on ``true``, 1.30/1.51 → 0.92/1.17 on ``grid``) but not the bias
  (``grid`` tibia (+0.028, -0.016, +0.003) mm): RMS 1.60/1.25, 1.28/1.49, 1.52/1.43 (``true``) and
  2.48/0.99, 1.28/1.35, 1.94/1.48 (``grid``) — no bone within 1.25× in both units.

What it would take in the device stage (not recommended on these numbers): two or more passes over
the trial (today's stage first), each frame's residual over the bones' regions from one render of
the three bones at the previous pass's poses (the neighbours' render it already makes), the mean of
frames t-1 and t+1 subtracted from the line integrals (one image a view, in place of the high-pass's
two blur passes), the neighbours' subtraction and the constant background as today; the bias that
today's stage leaves (the grid's leftover distortion, the tissue's pull) stays in every pass.

JSON on stdout (``--out``: also to a file, rewritten after each frame).
"""

from __future__ import annotations

import time

import numpy as np

from core.studies.tracking import _study_cli as cli

__all__ = ["averaged", "fit_bone", "neighbour_correction", "parse", "projected_shift", "residual_images",
           "run"]


def parse(name: str, pixels: int) -> dict:
    """A variant's parts (module docs): ``source`` (None for a plain method), ``K``,
    ``lowpass_px`` (at ``pixels``, or None), ``shift``, ``regressor``, ``method``."""
    head, sep, meth = name.partition(":")
    if not sep:
        return {"source": None, "K": 0, "lowpass_px": None, "shift": False, "regressor": False,
                "tissue_motion": False, "centred": False, "method": name}
    src, rest = head[:1], head[1:]
    i = 0
    while i < len(rest) and rest[i].isdigit():
        i += 1
    if src not in ("a", "b", "p", "q") or not i:
        raise ValueError(f"variant: expected <a|b|p><K>[l[σ]][s][g][c][t]:<method>, got {name!r}")
    K, flags = int(rest[:i]), rest[i:]
    low = None
    if "l" in flags:
        num = ""
        j = flags.index("l") + 1
        while j < len(flags) and (flags[j].isdigit() or flags[j] == "."):
            num += flags[j]
            j += 1
        low = (float(num) if num else 4.0) * pixels / 1024
        flags = flags.replace("l" + num, "")
    if set(flags) - set("sgtc") or K < 1 or ("t" in flags and src != "a") or ("c" in flags and src == "b"):
        raise ValueError(f"variant: unknown flags or K < 1 in {name!r}")
    return {"source": src, "K": K, "lowpass_px": low, "shift": "s" in flags, "regressor": "g" in flags,
            "tissue_motion": "t" in flags, "centred": "c" in flags, "method": meth}


def view_gains(Y, D, masks, highpass_px: float = 1.0) -> np.ndarray:
    """``(views, bones)`` gains of the bones' DRRs ``D (views, bones, H, W)`` in the line integrals
    ``Y (views, H, W)``: per view an unweighted least-squares fit of the high-passed images over
    the usable pixels (``masks``, None = all) of the bones' support (the tissue is smooth there)."""
    from core.similarity.likelihood import highpass

    out = []
    for v, y in enumerate(Y):
        sel = D[v].sum(axis=0) > 0
        if masks is not None and masks[v] is not None:
            sel &= np.asarray(masks[v], bool)
        yh = highpass(np.asarray(y, np.float32), highpass_px)[sel].astype(np.float64)
        A = np.stack([highpass(np.asarray(d, np.float32), highpass_px)[sel] for d in D[v]], axis=1)
        out.append(np.linalg.lstsq(A.astype(np.float64), yh, rcond=None)[0])
    return np.asarray(out)


def residual_images(renderer, frame, P, *, highpass_px: float | None = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """``(R (views, H, W), gains (views, bones))``: the frame's whole line-integral images minus
    the bones' DRRs at poses ``P (bones, 4, 4)`` times their gains (:func:`view_gains` on images
    high-passed by ``highpass_px``; None: every gain 1) — what the bones do not explain (tissue,
    walkway, mismatch, noise)."""
    Y = np.asarray(frame.images, np.float64)
    D = renderer.render(np.asarray(P, float)[None], roi="full").numpy()[0].astype(np.float64)
    g = view_gains(Y, D, frame.masks, highpass_px) if highpass_px else np.ones(D.shape[:2])
    return Y - np.einsum("vb,vbhw->vhw", g, D), g


def projected_shift(rig, center, P_from, P_to) -> np.ndarray:
    """``(views, 2)`` pixel motion ``(du, dv)`` of a bone's centroid ``center`` (model frame) from
    pose ``P_from`` to ``P_to`` (4 × 4)."""
    c = np.r_[np.asarray(center, float), 1.0]
    a = (np.asarray(P_from, float) @ c)[:3]
    b = (np.asarray(P_to, float) @ c)[:3]
    return np.asarray(rig.project(b)) - np.asarray(rig.project(a))


def averaged(residuals, *, lowpass_px: float | None = None, shifts=None) -> np.ndarray:
    """The mean of residual images ``(views, H, W)`` (a list), each first shifted by ``shifts``
    (per residual ``(views, 2)`` pixels ``(du, dv)``, or None), then low-passed by a Gaussian of
    ``lowpass_px`` when given."""
    from scipy import ndimage

    acc = None
    for i, R in enumerate(residuals):
        R = np.asarray(R, np.float64)
        if shifts is not None:
            R = np.stack([ndimage.shift(r, (float(s[1]), float(s[0])), order=1, mode="nearest")
                          for r, s in zip(R, shifts[i], strict=True)])
        acc = R if acc is None else acc + R
    A = acc / len(residuals)
    if lowpass_px:
        A = np.stack([ndimage.gaussian_filter(a, float(lowpass_px), mode="nearest") for a in A])
    return A


def neighbour_correction(D, gains, b: int) -> np.ndarray:
    """``(views, H, W)``: ``Σ_o (g_o - 1) D_o`` over the bones ``o != b`` — what to subtract with the
    residual so that the fit's neighbours, subtracted at gain 1, end up at the gains ``gains
    (views, bones)`` the residuals were taken with (``D (views, bones, H, W)`` their DRRs at the
    frame's start poses): the residual holds ``(g*_o - g_o) D_o`` of them, not ``(g*_o - 1) D_o``."""
    c = np.asarray(gains, np.float64) - 1.0
    c[:, b] = 0.0
    return np.einsum("vb,vbhw->vhw", c, np.asarray(D, np.float64))


def fit_bone(ts, frame, b: int, P_start, name: str, pixels: int, margin_px: int, A=None,
             regressor: bool = False) -> np.ndarray:
    """Bone ``b``'s refined pose ``(4, 4)`` in ``frame`` by method ``name``
    (:func:`core.studies.tracking.background_fit.method`) from ``P_start`` (all bones; the others
    subtracted there at gain 1), with the tissue image ``A (views, H, W)`` subtracted from the line
    integrals before the method's high-pass (or, ``regressor``, fitted with its own gain)."""
    from core.similarity.likelihood import highpass
    from core.studies.tracking.background_fit import _crop, method
    from core.tracking.cost import search_roi, snap_roi
    from core.tracking.likelihood_cost import LikelihoodCost

    m = ts.models[b]
    views = tuple(range(len(ts.scene.rig)))
    roi = snap_roi(search_roi(ts.renderer, P_start[b], b, views=views, center=m.centroid, reach_mm=1.0,
                              margin_px=margin_px), ts.renderer, views)
    oth = [k for k in range(len(ts.names)) if k != b]
    co, ro = method(name, pixels)
    hp = co.get("highpass_px") or None
    if A is not None and regressor:
        co["regressors"] = [_crop(A[v], roi[i])[None] for i, v in enumerate(views)]
    elif A is not None:
        co["highpass_px"] = None
    cost = LikelihoodCost(ts.renderer, frame, bone=b, base_pose=P_start[b], center=m.centroid, roi=roi,
                          others=(P_start[oth], oth) if oth else None, others_gain=False, **co)
    if A is not None and not regressor:  # y - A, then the method's high-pass (the DRRs filtered alike)
        sub = [r - _crop(A[v], roi[i])[: r.shape[0], : r.shape[1]]
               for i, (v, r) in enumerate(zip(views, cost.fluoro_rois, strict=True))]
        cost.fluoro_rois = tuple(highpass(s, hp) if hp else np.asarray(s, np.float32) for s in sub)
        cost.highpass_px = hp
    r = cost.refine(iters=6, **ro)
    return cost.poses(np.asarray(r["x"])[None])[0]


class _Frames:
    """Frame images (per set, frame, draw) and their residuals (per poses' key), cached."""

    def __init__(self, src, ts0, gain_hp: float | None = None) -> None:
        self.src, self.ts0, self.gain_hp = src, ts0, gain_hp
        self._L: dict = {}
        self._img: dict = {}
        self._res: dict = {}

    def frame(self, st: str, f: int, s):
        from core.studies.tracking.background_fit import frame_images
        from core.tracking.cost import prepare_frame

        key = (st, f, s)
        if key not in self._img:
            if f not in self._L:
                self._L = {f: self.ts0.scene.line_integrals(f, renderer=self.ts0._scene_renderer)}
            self._img[key] = prepare_frame(frame_images(self.src, st, self._L[f],
                                                        None if s is None else 1000 * f + s))
        return self._img[key]

    def residual(self, st: str, f: int, s, P, key) -> tuple[np.ndarray, np.ndarray]:
        """:func:`residual_images` of frame ``f`` (set ``st``, draw ``s``) at poses ``P``."""
        k = (st, f, s, key)
        if k not in self._res:
            self._res[k] = residual_images(self.ts0.renderer, self.frame(st, f, s), P,
                                           highpass_px=self.gain_hp)
        return self._res[k]

    def tissue(self, f: int) -> np.ndarray:
        """The soft tissue's true line integrals of frame ``f`` through the generator's PSF
        (:func:`core.studies.tracking.background_fit.tissue_images`; the ``t`` probe only)."""
        from core.studies.tracking.background_fit import tissue_images

        k = ("tissue", f)
        if k not in self._res:
            self._res[k] = tissue_images(self.ts0, f)
        return self._res[k]

    def drop_before(self, f: int) -> None:
        """Forget frames and residuals before ``f`` (memory)."""
        self._img = {k: v for k, v in self._img.items() if k[1] >= f}
        self._res = {k: v for k, v in self._res.items() if k[1] >= f}  # ("tissue", f) alike


def run(*, pixels: int = 256, voxel: float = 1.0, n_frames: int = 20, frames=range(4, 20, 4), seeds: int = 2,
        sets=("true", "grid"), variants=("hp4+r", "a4:hp0+r", "a4:hp2+r", "a4:hp4+r"), bones=None,
        pose_error: float = 0.05, residual_gain_hp: float | None = None, seed: int = 0,
        device: str | None = "cpu", checkpoint=None) -> dict:
    """Run the study (module docs); returns the JSON-ready results. ``b`` variants run every frame
    from 0 to the last of ``frames``; statistics are over ``frames``."""
    from core.studies.tracking.acceptance import cramer_rao, pose_errors
    from core.studies.tracking.background_fit import _Sources
    from core.studies.tracking.tissue_regressor import _summary, estimated_poses
    from core.tracking.register import RegistrationOptions

    t0 = time.perf_counter()
    frames = sorted(int(f) for f in frames)
    src = _Sources(pixels, voxel, n_frames, seed, device)
    ts0 = src.scene(sets[0])
    names = ts0.names
    bones = list(range(len(names))) if bones is None else [int(b) for b in bones]
    margin = RegistrationOptions().margin_px
    V = {v: parse(v, pixels) for v in variants}
    for v, p in V.items():
        if p["source"] and frames[0] < p["K"]:
            raise ValueError(f"{v}: needs frames >= K = {p['K']}")
    chained = [v for v in variants if V[v]["source"] == "b"]
    todo = sorted(set(frames) | (set(range(frames[-1] + 1)) if chained else set()))
    out = cli.header("core.studies.tracking.temporal_tissue", pixels=pixels, voxel_mm=voxel,
                     n_frames=n_frames, frames=frames, seeds=seeds, sets=list(sets), pose_error=pose_error,
                     residual_gain_hp=residual_gain_hp, variants=V)
    bound = cramer_rao(ts0, frames)
    out["bound"] = bound
    out["setup_s"] = time.perf_counter() - t0
    errs: dict = {}
    est: dict = {}  # (set, variant, draw) -> {frame: (bones, 4, 4) refined poses}
    cache = {st: _Frames(src, ts0, residual_gain_hp) for st in sets}
    fits: dict = {}  # (set, frame, draw, bone, method) -> pose of a fit without a residual (shared)
    first: dict = {}  # (set, frame, draw) -> today's form's poses (all bones; the p source)
    kmax = max([V[v]["K"] for v in variants] + [0])
    for v, p in V.items():
        reach = p["K"] * (2 if p["source"] == "q" else 1)
        if frames[0] < reach or (p["centred"] and frames[-1] + reach >= n_frames):
            raise ValueError(f"{v}: needs frames within K (2K for q) of 0 and n_frames = {n_frames}")
    def others(p, f):  # the frames whose residuals frame f uses
        after = range(f + 1, f + p["K"] + 1) if p["centred"] else ()
        return [*range(f - p["K"], f), *after]

    def residual_fit(st, f, s, v, Ps, tag):
        """Frame f's poses by variant v with the residuals of its other frames at poses Ps."""
        p, ts, fc = V[v], src.scene(st), cache[st]
        prev = others(p, f)
        P0 = estimated_poses(ts0, f, pose_error, seed)
        RG = [fc.residual(st, k, s, Ps[i], tag) for i, k in enumerate(prev)]
        R = [x[0] for x in RG]
        if p["tissue_motion"]:  # probe: the tissue's true change since t - k added back
            R = [r + fc.tissue(f) - fc.tissue(k) for r, k in zip(R, prev, strict=True)]
        gbar = np.mean([x[1] for x in RG], axis=0)
        D0 = ts0.renderer.render(P0[None], roi="full").numpy()[0]
        P_hat = P0.copy()
        for b in bones:
            c = ts0.models[b].centroid
            sh = [projected_shift(ts0.scene.rig, c, Pk[b], P0[b]) for Pk in Ps] if p["shift"] else None
            Ab = averaged(R, lowpass_px=p["lowpass_px"], shifts=sh) + neighbour_correction(D0, gbar, b)
            P_hat[b] = fit_bone(ts, fc.frame(st, f, s), b, P0, p["method"], pixels, margin, Ab,
                                p["regressor"])
        return P_hat

    def passes(st, f, s, v, level):
        """Frame f's poses after ``level`` passes: 1 today's form, then variant v with the residuals
        at the previous pass's poses (cached)."""
        key = (st, f, s, v[1:] if level > 1 else "", level)  # p and q of the same form share passes
        if key not in first:
            if level == 1:
                P0 = estimated_poses(ts0, f, pose_error, seed)
                first[key] = np.stack([fit_bone(src.scene(st), cache[st].frame(st, f, s), b, P0, "hp4+r",
                                                pixels, margin) if b in bones else P0[b]
                                       for b in range(len(names))])
            else:
                Ps = [passes(st, k, s, v, level - 1) for k in others(V[v], f)]
                first[key] = residual_fit(st, f, s, v, Ps, f"pass{level - 1}:{v}")
        return first[key]

    for f in todo:
        P_true = ts0.truth(f)
        P0 = estimated_poses(ts0, f, pose_error, seed)
        for st in sets:
            ts, fc = src.scene(st), cache[st]
            for s in [None, *range(seeds)]:
                frame = fc.frame(st, f, s)
                for v in variants:
                    p = V[v]
                    if f not in frames and p["source"] != "b":
                        continue
                    use = p["source"] is not None and f >= p["K"]
                    meth = p["method"] if use or p["source"] is None else "hp4+r"
                    if not use:
                        P_hat = P0.copy()
                        for b in bones:
                            key = (st, f, s, b, meth)
                            if key not in fits:
                                fits[key] = fit_bone(ts, frame, b, P0, meth, pixels, margin)
                            P_hat[b] = fits[key]
                    elif p["source"] in ("p", "q"):
                        P_hat = passes(st, f, s, v, 2 if p["source"] == "p" else 3)
                    else:
                        Ps = [ts0.truth(k) if p["source"] == "a" else est[(st, v, s)][k]
                              for k in others(p, f)]
                        P_hat = residual_fit(st, f, s, v, Ps, "true" if p["source"] == "a" else v)
                    if p["source"] == "b":
                        est.setdefault((st, v, s), {})[f] = P_hat
                    if f in frames:
                        for b in bones:
                            e = pose_errors(P_hat[b], P_true[b], ts0.models[b].centroid)
                            d = errs.setdefault(st, {}).setdefault(v, {}).setdefault(
                                names[b], {"free": [], "noisy": []})
                            if s is None:
                                d["free"].append(e)
                                d["noisy"].append([])
                            else:
                                d["noisy"][-1].append(e)
            fc.drop_before(f - 2 * kmax)
        fits = {k: x for k, x in fits.items() if k[1] == f}
        first = {k: x for k, x in first.items() if k[1] >= f - 2 * kmax}
        for key in [k for k in est if min(est[k], default=f) < f - 8]:
            est[key] = {k: x for k, x in est[key].items() if k >= f - 8}
        if f in frames:
            out["results"] = {st: {v: {nm: _summary(d, bound.get(nm)) |
                                       {"free_errors": np.round(d["free"], 5).tolist()}
                                       for nm, d in vm.items()} for v, vm in sm.items()}
                              for st, sm in errs.items()}
        # (a frame only the chained variants need: its progress, the frames done as they were)
        cli.frame_done(out, f, t0, checkpoint, [x for x in frames if x <= f] if f in frames else None)
    return out


def table(res: dict) -> list[str]:
    """One line per set, variant and bone: RMS, bias and spread over the bound (mm / degrees)."""
    rows = []
    for st, sm in res.get("results", {}).items():
        for v, vm in sm.items():
            for nm, s in vm.items():
                rows.append(f"{st:5s} {v:14s} {nm:10s} rms {s.get('rms_over_bound')} bias "
                            f"{s.get('bias_over_bound')} spread {s.get('spread_over_bound')}")
    return rows


def main(argv=None) -> int:
    p = cli.parser("core.studies.tracking.temporal_tissue", __doc__)
    cli.add_scene(p, frames="4,8,12,16", sets="true,grid")
    p.add_argument("--variants", default="hp4+r,a4:hp0+r,a4:hp2+r,a4:hp4+r")
    p.add_argument("--bones", default="", help=cli.BONES_HELP)
    p.add_argument("--pose-error", type=float, default=0.05, help="mm / degrees per axis of the start poses")
    p.add_argument("--residual-gain-hp", type=float, default=None,
                   help="the residuals' bone gains fitted on images high-passed by this many px (default 1)")
    cli.add_output(p, table=True)
    a = p.parse_args(argv)
    res = run(pixels=a.pixels, voxel=a.voxel, n_frames=a.n_frames, frames=cli.ints(a.frames), seeds=a.seeds,
              sets=cli.names(a.sets), variants=cli.names(a.variants), bones=cli.ints(a.bones) or None,
              pose_error=a.pose_error, residual_gain_hp=a.residual_gain_hp, checkpoint=cli.checkpoint(a))
    return cli.finish(res, a, table)


if __name__ == "__main__":
    raise SystemExit(main())
