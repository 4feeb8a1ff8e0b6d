"""The opt-in final stage of a registration (:class:`core.tracking.register.RegistrationOptions`
``final``; the register module's docs): the similarity's optimum refined by weighted least
squares on the device (:mod:`core.tracking.engine_likelihood`), its confidence the refinement's
sandwich covariance.

The region's pixels (:class:`FinalModel`, the module's :data:`MODEL`)
---------------------------------------------------------------------
The weights are the expected counts over the bone's search region. Two optional changes of
them, for frames where structure the model lacks (untracked bones such as the fibula, tracked
neighbours in sequential tracking, soft-tissue edges) overlaps the bone:

* ``support_px``: only the bone's DRR support at the similarity's pose, grown by that many
  pixels, counts (elsewhere the pixels inform the bone's pose only through the high-pass's
  reach, and carry every neighbour's edges);
* ``robust``: after a first refinement, each pixel's weight is multiplied by a factor that falls
  where the residual is structurally large — the local RMS of the weighted residual (a Gaussian
  window of ``robust_sigma_px``) over its median in the view, ``u``: ``1 / (1 + (u / k)²)`` with
  ``k = robust`` (``robust_kind="cauchy"``) or ``min(1, k / u)`` (``"huber"``) — and the pose is
  refined again from there (``rounds`` times). The confidence stays the first refinement's
  sandwich (plus the stage's move, ``final_confidence="sandwich+move"``): its residual holds the
  unmodelled structure the robust weights then set aside, and that is what the error is made of
  where a bias dominates; the robust refinement's own sandwich (``covariance_robust``) sees the
  noise alone.

Measured on the harder acceptance trial (:mod:`core.studies.tracking.hard_trial`, 1024², 0.5 mm,
20 frames, one NVIDIA H200; ``resources/benchmarks/tracking_hard_final_h200.json``), GC of the
gradient components, sequential/joint, RMS: the GC optimum alone (no stage) tibia 0.129/0.111°,
talus 0.177/0.149°, calcaneus 0.114/0.091°; the plain stage (``robust=None``) tibia 0.094/0.098°,
talus 0.161/0.140°, calcaneus 0.089/0.087° but 0.052/0.054 mm (0.038/0.035 without); with
``robust=2.5`` tibia 0.077/0.082° (0.042 mm), talus 0.159/0.135° (0.042/0.037 mm), calcaneus
0.082/0.081° (0.035/0.034 mm). The robust refinement's own sandwich put 5 % (tibia) and 30-70 %
(calcaneus) of frames within 2σ on all six axes: the tibia is 0.03 mm off in y in every frame
(the trial's 3 % wrong distortion inverse), a bias no noise model sees; with the first
refinement's sandwich (+ move) 100 %, the talus 80 % (96 % of its single axes). ``support_px=6``
changed nothing measurable over ``robust`` alone. On the acceptance trial's first 30 frames (same
calls): talus alone 1.47/1.35 → 1.50/1.36× its bound (mm/°), three bones jointly tibia 2.50/1.75 →
2.39/1.47×, talus 1.42/1.46 → 1.46/1.50×, calcaneus 2.01/1.33 → 2.01/1.32×. The stage's default
(:data:`MODEL`) is ``robust=2.5``; it costs a second refinement (8.0-8.5 steps instead of
3.8-4.2; 72-94 ms per bone-frame instead of 17-27 ms in those runs, which shared the GPU, with
the robust factors filtered on the host). The factors are now filtered on the device
(:data:`ROBUST_ON_DEVICE`; :func:`robust_factors` took ~240 ms for two 640² regions on a 2-core
CPU): on one NVIDIA H200 alone (``resources/benchmarks/tracking_final_reject_h200.json``) the
stage took 44-46 ms per bone-frame on the harder trial (8.2-8.3 steps) and, on the acceptance
trial (1024², 100 frames), 40.9 ms jointly (12.0 ms set-up, 8.6 steps; the plain stage 20.1 ms,
4.4 steps) and 26.0 ms for the talus alone. Where it went (20 frames of that trial, one NVIDIA
H200, each function timed with a synchronisation around it; per bone-frame, three bones jointly /
the talus alone; ``resources/benchmarks/tracking_final_speed_h200.json``): the set-up 10.4 / 4.6 ms
(the host regions 2.5 / 1.7 ms, the rest host arrays uploaded from pageable memory and the
neighbours' DRRs read back), the steps 15.7 / 11.7 ms (1.8 / 1.4 ms each: DRRs 0.56, blur 0.45,
the host's solve 0.29), the robust factors 6.3 / 4.4 ms (their median on the host) and two
sandwiches 6.2 / 4.6 ms. Since then the set-up runs on the device without reading back
(:meth:`~core.tracking.engine_likelihood.LikelihoodEngine.set_frame`), the median is taken on the
device, a sandwich synchronises once and sums half the lags, the solve takes the views at once,
the robust refinement's own sandwich is skipped (:data:`ROBUST_SANDWICH`) and its first step
reuses the robust factors' images, with the same poses, σ, steps and flags (on a 192² CPU trial,
three bones jointly and sequentially and the talus alone: poses within 5e-15, the solve's
rounding).

Soft tissue (:attr:`FinalModel.tissue`)
---------------------------------------
The high-pass takes the soft tissue's smooth line integral out, and with it the bone's own
low-frequency information. A lab that has a CT of the whole foot can give the stage its soft
tissue instead: ``FinalModel(tissue=[(CTVolume, bone), ...])``, each volume following the pose of
one of the registration's bones (the foot's soft tissue the calcaneus, the shank's the tibia). Per
bone-frame the stage renders the volumes on the device at the current estimate of those poses —
its own bone at the similarity's pose, the neighbours at the poses it is given (joint rounds: the
round's; sequential tracking: :func:`stage_neighbours`) — as the frame shows them (through
``tissue_psf``, a PSF estimated from calibration images, as fluence), high-passed like the frame,
and fits it with a gain of its own per view at every pose (one more entry of the engine's moments
table, :meth:`~core.tracking.engine_likelihood.LikelihoodEngine.set_tissue`; ``tissue_each``: each
volume its own gain; ``tissue_again``: rendered again at the first refinement's pose). A volume
whose bone has no estimate in the registration (a bone not tracked) is left out; without volumes
the stage is the one measured above, to the bit.

Measured (:mod:`core.studies.tracking.tissue_stage`, the acceptance trial at 1024², 0.5 mm, 100
frames, grid-estimated distortion correction, measured glare undone; the tissue the generator's
resampled onto a 4 mm grid, through the estimated PSF; one NVIDIA H200,
``resources/benchmarks/tracking_tissue_stage_h200.json``), RMS over the Cramér–Rao bound mm/° of
tibia, talus, calcaneus, three bones jointly: high-pass 4 px 1.56/1.42, 1.38/1.29, 1.21/1.38 and
with the tissue 1.64/1.47, 1.36/1.28, 1.21/1.37 (stage 15.3 → 16.8 ms per bone-frame); high-pass
8 px 1.72/1.46, 1.31/1.31, 1.15/1.42 and with the tissue 1.92/1.66, 1.17/1.18, 1.15/1.34 (21.9 →
22.9 ms). Sequential tracking of the three bones alike (high-pass 8 px with the tissue 1.91/1.65,
1.17/1.19, 1.14/1.33). The regressor lets the wider high-pass keep the talus's low frequencies —
the talus is within 1.25× its bound only so — but it costs the tibia 0.2×; rendering the tissue
again after the first refinement (``tissue_again``) or a gain per part (``tissue_each``) changed
every ratio by 0.03 or less. The tibia's loss is the 4 mm volume's error, not the stage's
(:mod:`core.studies.tracking.tissue_tibia`: its resampling stripes, smoothed skin and cut shank
top cross the tibia's edges; the first-order bias from the true poses over the 100 frames has the
tracked offset's shape): with a 2 mm volume for every bone (``tissue_regressor.user_tissue("fine")``,
``resources/benchmarks/tracking_tissue_tibia_h200.json``, 8 px, three jointly) 1.54/1.36,
1.15/1.19, 1.12/1.30 — every bone better than without tissue. Use a 2 mm tissue volume; with only
a 4 mm one, ``bones={tibia: BoneStage(highpass_px=4.0, tissue=False)}`` (1.56/1.42, 1.17/1.19,
1.15/1.34). The regressor stays opt-in (the lab must have the CT).

The round field's rim (:attr:`FinalModel.rim_sigmas`): usable pixels within that many σ of the
high-pass of a black one weighted 0 (the field's ``-log(floor)`` step, spread by the high-pass,
biased the tibia at 8 px); measured and why opt-in: :mod:`core.tracking.likelihood_rim`.

Per-bone settings (:attr:`FinalModel.bones`)
--------------------------------------------
``FinalModel(bones={2: BoneStage(highpass_px=4.0, tissue=False)})``: bone 2's stage (bone indices
of the registration's renderer, as the tissue's) with its own high-pass σ instead of the
registration options' ``final_highpass_px``, and without the tissue regressor (the volumes still
follow that bone's pose in the other bones' stages) — e.g. the 8 px high-pass with the tissue for
the talus and the calcaneus, 4 px without it for the tibia (the measurements above). A bone
without an entry, and a model without ``bones``, give the stage as before, to the bit. The model
is the module's :data:`MODEL` (set by :func:`final_model`), not a field of
:class:`~core.tracking.trial.TrackingOptions`: ``talus track --final likelihood`` runs the default
model; :meth:`FinalModel.to_dict` records the overrides (``"bones"``) only where there are any.

The stage's result keeps the similarity's (:class:`LikelihoodFit` ``similarity``), so that a
frame whose stage move is out of line with the bone's other frames keeps the similarity's pose
(:func:`rejected`, :func:`core.tracking.frame_step.stage_move_check`). In sequential tracking the
frame step gives the stage the bones registered in the frame and the others' guesses to subtract
(:func:`stage_neighbours`). In joint registration (:func:`core.tracking.joint.register_together`)
the bones' stages run side by side (:func:`final_stages`): every bone's step is enqueued and the
host takes each one's result as soon as it is ready, so one bone's host work (the solve, the next
design and its DRR table) overlaps the device's work on the others'; each bone's iterates, steps
and result are those of its own stage (identical on a 192² CPU trial, three bones jointly).

:func:`final_model` sets :data:`MODEL` for a block (studies compare models in one process). Where
the stage's time goes (one NVIDIA H100: 13.9 ms per bone-frame at 4 px, 18.6 ms at 8 px, three
bones jointly) and what it would need to fit the speed goal: :mod:`core.tracking.likelihood_fast`;
since, with fewer steps (a refinement ends at a step the data barely resolve, the robust round
from the first refinement's last design, :data:`ROBUST_FROM_LAST`), 4.99 ms at 4 px and 8.55 ms at
8 px on one NVIDIA H100 (:mod:`core.tracking.engine_likelihood`: Fewer steps).
The settings and records (:class:`FinalModel`, :class:`BoneStage`, :class:`LikelihoodFit`,
:func:`rejected`) are in :mod:`core.tracking.likelihood_model` (re-exported here).
"""

from __future__ import annotations

from collections.abc import Sequence
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import replace

import numpy as np

from .cost import CostTimer, FrameImages, OutsideViewError, search_roi, snap_roi
from .engine_likelihood import (
    TO_TOL,
    LikelihoodEngine,
    StepClock,
    likelihood_engine,
    run_side_by_side,
    run_steps,
    same_array,
)
from .likelihood_host import _support_mask, robust_factors, stage_params
from .likelihood_model import BoneStage, FinalModel, LikelihoodFit, rejected
from .likelihood_rim import apply_rim
from .likelihood_tissue import _set_tissue, tissue_renderer
from .roi import support_points

__all__ = ["CONFIRM_FRACTION", "MODEL", "BoneStage", "FinalModel", "LikelihoodFit", "confirm_move",
           "final_model", "final_stage", "final_stage_steps", "final_stages", "rejected", "robust_factors",
           "stage_neighbours", "stage_prefetch", "tissue_renderer"]


#: the final stage's model of the region's pixels (:class:`FinalModel`)
MODEL = FinalModel()
#: the robust factors filtered on the device (:meth:`~core.tracking.engine_likelihood.LikelihoodEngine.
#: robust_weights`; off: :func:`robust_factors` on the host, as first measured)
ROBUST_ON_DEVICE = True
#: the robust refinement's own sandwich covariance computed (``covariance_robust`` of
#: :func:`_refine`, for studies); off, the stage's result is the same (its confidence is the first
#: refinement's), ``covariance_robust`` is NaN and the engine's autocorrelation None after it: one
#: sandwich (its residual's autocovariance and meat on the device) fewer per bone-frame
ROBUST_SANDWICH = False
#: the robust round from the first refinement's last design (its centre and step: the images on the
#: device, the weights the same), without a step of its own there: the robust factors from that
#: step's residual, the robust refinement started at that centre with its images (no render where
#: it stops at once, :data:`~core.tracking.engine_likelihood.STOP_PRED`). Off: a step at the first
#: refinement's result (rendered) for the factors, as first measured. Measured with it:
#: :mod:`core.tracking.engine_likelihood` (module docs: Fewer steps).
ROBUST_FROM_LAST = True
#: The first refinement's sandwich (the stage's confidence) enqueued after the robust refinement's first
#: step (which takes the same images: :data:`ROBUST_FROM_LAST`), reading the frame's weights kept
#: before the robust factors (``_w0``), with an event of its own: the host waits for that step
#: without it and solves the step while the device computes it. The same inputs and kernels: the same
#: covariance, steps and poses. Off: enqueued before the robust factors, as first written (a step's
#: wait then waits for it too). Measured alone on one NVIDIA H100 (97b2893, the talus at 1024², 40 frames,
#: three repeats alternated, ``stage_one_bone --variants base,prefetch,after``,
#: ``tracking_stage_one_bone_97b2893_h100.json``): the stage 4.30-4.67 ms a bone-frame off, 3.65-4.13 on
#: (median over the frames, per run), the frame after the first 8.58-8.90 → 7.17-7.96 ms, the host's
#: waits 1.42 → 1.23 ms; poses within 7e-13 mm (the device's float64 atomics' order). On since; three
#: bones jointly not measured (the same values). An earlier run at 1d5ed65 (4.55 against 4.52 ms) had it
#: only with the regions over 512-pixel chunks (0.23 ms more device work, since removed).
SANDWICH_AFTER_STEP = True
#: Opt-in: the stage's region the box of the bone's DRR support (:func:`~core.tracking.roi.support_points`,
#: the hull of the volume's positive voxels) at the similarity's pose instead of its volume box's,
#: grown as before (1 mm of reach, the options' ``margin_px``) plus this many high-pass σ (the
#: high-passed DRR reaches beyond the bone's outline). At 1024² on the acceptance trial the
#: regions are 39-54 % of the box's area (grown by 0 σ; the DRRs, blurs, moments and sandwich scale
#: with it); the pixels left out change the poses. Measured on one NVIDIA H100 (30 frames, three bones
#: jointly, 4 px, against the box in the same call; ``resources/benchmarks/tracking_stage_h3_h100.json``):
#: 8 σ (32 px) 3.53/2.93 ms per bone-frame against 4.03/3.75, errors over the bound (tibia, talus,
#: calcaneus mm/°) 1.648/1.446, 1.439/1.381, 1.361/1.249 against 1.638/1.449, 1.439/1.401, 1.358/1.235,
#: 2σ coverage the same (100/90/100 % of the axes), no frame over 4×, poses within 0.0095 mm / 0.023°;
#: 4 σ 3.13/3.12 ms, 2 σ 3.49/3.29, 0 σ 4.18/3.89 but the calcaneus's rotation 1.279-1.289× and its
#: coverage 91-97 %; the device's time 3.46 → 2.74-2.80 ms (0 and 2 σ). None: the volume box, as
#: first measured.
REGION_OUTLINE: float | None = None


@contextmanager
def final_model(model: FinalModel | None = None, **kw):
    """:data:`MODEL` is ``model`` (or ``FinalModel(**kw)``) inside the block."""
    global MODEL
    old = MODEL
    MODEL = model if model is not None else FinalModel(**kw)
    try:
        yield MODEL
    finally:
        MODEL = old


_PLAIN_REFINE = LikelihoodEngine.refine  # (a study may wrap it: _engine_refine)

#: the neighbours (``(poses, bones)``) a final stage subtracts where its registration gives none
_NEIGHBOURS: ContextVar = ContextVar("final_stage_neighbours", default=None)


@contextmanager
def stage_neighbours(others):
    """Inside the block, a final stage whose registration has no neighbours (``others`` None)
    subtracts ``others = (poses, bones)`` (sequential tracking: the bones registered in the frame
    and the others' predicted poses, :mod:`core.tracking.frame_step`); the similarity's search is
    not changed. ``others`` None: nothing changes."""
    token = _NEIGHBOURS.set(others)
    try:
        yield
    finally:
        _NEIGHBOURS.reset(token)


def _refine(eng, o, model: FinalModel, tissue=None) -> dict:
    """The engine's refinement with ``model``'s region and weights (module docs)."""
    return run_steps(_refine_steps(eng, o, model, tissue))


def _engine_refine(eng, *a, **k):
    """The engine's :meth:`~core.tracking.engine_likelihood.LikelihoodEngine.refine_steps`, or, where
    a study wrapped its ``refine`` (a probe of what each refinement saw), that, run to its end."""
    if type(eng).refine is not _PLAIN_REFINE:
        return eng.refine(*a, **k)
    return (yield from eng.refine_steps(*a, **k))


_H0 = np.full(6, 0.05)  # (refine_steps' half-steps: its default step)


def _after_first_launch(steps, launch, *args):
    """The refinement ``steps`` (a generator of :meth:`~core.tracking.engine_likelihood.LikelihoodEngine.
    refine_steps`' kind) with ``launch(*args)`` enqueued after its first step's work, before its
    first wait (:data:`SANDWICH_AFTER_STEP`)."""
    try:
        nxt = next(steps)
    except StopIteration as stop:
        launch(*args)
        return stop.value
    launch(*args)
    yield nxt
    return (yield from steps)


def _refine_steps(eng, o, model: FinalModel, tissue=None):
    """:func:`_refine` as a generator (its value the result) that yields where it would wait for
    the device (:meth:`~core.tracking.engine_likelihood.LikelihoodEngine.refine_steps`).
    ``tissue``: called with the first refinement's ``x`` before the robust rounds (the tissue
    rendered again there, :attr:`FinalModel.tissue_again`)."""
    mask = None
    if model.support_px is not None:
        mask = _support_mask(eng, model.support_px)
        eng.scale_weights(mask)
    if model.robust is None:
        return (yield from _engine_refine(eng, iters=o.final_iters))
    # the first refinement's sandwich launched, taken after the robust factors' step (no wait of its
    # own); SANDWICH_AFTER_STEP: launched after the robust refinement's first step (see there)
    plain = type(eng).refine is _PLAIN_REFINE
    defer = plain and SANDWICH_AFTER_STEP and not ROBUST_SANDWICH and tissue is None and mask is None
    later = ("defer" if defer else "later") if plain else True
    out = yield from _engine_refine(eng, iters=o.final_iters, sandwich=later)
    first = out  # its sandwich is the stage's confidence (module docs)
    hinv = out.pop("sandwich", None)
    pending = out.pop("sandwich_s", None)  # (its design's step: launched before the images change)
    n_it = int(out["iterations"])
    for _ in range(int(model.rounds)):
        if not np.isfinite(out["x"]).all():
            break
        last = out.get("design") if out is first and tissue is None and mask is None else None
        if tissue is not None:
            tissue(out["x"])
            tissue = None
        if (ROBUST_FROM_LAST and not TO_TOL.get() and last is not None and eng._last is not None
                and same_array(eng._last[2], last[0])):
            # the factors from the last design's step (the same weights and images), the robust
            # refinement from its centre (ROBUST_FROM_LAST); the sandwich taken at the end
            (start, s), factor_step = last, 0
            if ROBUST_SANDWICH and hinv is not None:  # (the robust refinement's sandwich uses its buffers)
                yield
                first["covariance"], hinv = eng.sandwich_result(hinv), None
            if pending is not None and not same_array(eng._last[3], _H0):  # (its first step renders)
                eng.sandwich_launch(pending)
                pending = None
        else:
            if pending is not None:  # (before this step's images replace the design's)
                eng.sandwich_launch(pending)
                pending = None
            # the residual over the whole region (its typical pixel the noise's scale), then the
            # factors within the support
            start, factor_step = out["x"], 1
            eng.reset_weights()
            eng.step_launch(start, np.full(6, 0.05))  # (refine's design: its first step takes these images)
            yield
            s = eng.step_result()
            if hinv is not None:  # (the device has done it: it came before this step)
                first["covariance"], hinv = eng.sandwich_result(hinv), None
        if ROBUST_ON_DEVICE and mask is None:  # (the factors' filter and the product: one piece)
            eng.robust_scale(s, model.robust, sigma_px=model.robust_sigma_px, kind=model.robust_kind)
        else:
            if ROBUST_ON_DEVICE:
                f = eng.robust_weights(s, model.robust, sigma_px=model.robust_sigma_px,
                                       kind=model.robust_kind).numpy() * mask
            else:
                e = eng.residual(s)
                used = eng._w.numpy() > 0
                f = robust_factors(e, used, model.robust, sigma_px=model.robust_sigma_px,
                                   kind=model.robust_kind)
                f = f if mask is None else f * mask
            eng.scale_weights(f)
        # (the robust refinement's own sandwich where the first's is known to have failed)
        own = ROBUST_SANDWICH or (hinv is None and not np.isfinite(first["covariance"]).all())
        steps = _engine_refine(eng, start, iters=o.final_iters, sandwich=own, reuse=True)
        if pending is not None:  # its first step on the design's images: the sandwich after it
            steps = _after_first_launch(steps, eng.sandwich_launch, pending, eng._w0)
            pending = None
        out = yield from steps
        n_it += factor_step + int(out["iterations"])
    if pending is not None:  # (no robust round ran)
        eng.sandwich_launch(pending)
    if hinv is not None:  # (no robust round, or one from the last design: the device has done it since)
        yield
        first["covariance"] = eng.sandwich_result(hinv)
        d = out.get("design")
        if (not np.isfinite(first["covariance"]).all() and out is not first and d is not None
                and not np.isfinite(out["covariance"]).all()):  # (then the robust refinement's own)
            try:
                hr = np.linalg.inv(d[1]["JJ"])
            except np.linalg.LinAlgError:
                hr = None
            if hr is not None:
                eng.sandwich_launch(d[1])
                yield
                out["covariance"] = eng.sandwich_result(hr)
    out["iterations"] = n_it
    out["covariance_robust"] = out["covariance"]
    if np.isfinite(first["covariance"]).all():
        out["covariance"] = first["covariance"]
        out["covariance_independent"] = first["covariance_independent"]
    return out



def final_stage(renderer, frame: FrameImages, res, *, bone: int, initial_pose, center, options,
                views: Sequence[int], others=None):
    """``res`` (a :class:`core.tracking.register.RegistrationResult`) refined by the final stage of
    ``options`` (its :class:`~core.tracking.register.RegistrationOptions`; module docs): a
    registration result, ``res`` itself without a stage or after a cancelled one.
    ``initial_pose``: the registration's (``x`` is relative to it). This module does not import
    :mod:`core.tracking.register`, which calls it."""
    return run_steps(final_stage_steps(renderer, frame, res, bone=bone, initial_pose=initial_pose,
                                       center=center, options=options, views=views, others=others))


def final_stages(renderer, frame: FrameImages, calls: Sequence[tuple]) -> list:
    """:func:`final_stage` of several bones in one frame side by side (joint registration,
    :func:`core.tracking.joint.register_together`): ``calls`` per bone ``(res, kwargs)`` of
    :func:`final_stage`; their results in that order, each the one :func:`final_stage` gives (the
    same iterates: each bone's refinement on its own engine, which keeps its own copy of the
    rendered images meanwhile). Each bone's steps are enqueued and the host takes each one's
    result as it comes (:func:`~core.tracking.engine_likelihood.run_side_by_side`), so one bone's
    host work overlaps the others' device work; each bone's ``likelihood_s`` is the time spent on
    its own (set-up, host work and waits: together the stages' wall time)."""
    bones = [int(kw["bone"]) for _, kw in calls]
    if len(calls) < 2 or len(set(bones)) < len(bones) or final_stage is not _PLAIN_FINAL_STAGE:
        # (one bone; a bone twice: one engine; a study's wrapper of final_stage: it sees every call)
        return [final_stage(renderer, frame, res, **kw) for res, kw in calls]
    clocks = [StepClock() for _ in calls]
    gens = [final_stage_steps(renderer, frame, res, **kw, clock=c, side_by_side=True)
            for (res, kw), c in zip(calls, clocks, strict=True)]
    return run_side_by_side(gens, clocks)


_PLAIN_FINAL_STAGE = final_stage  # (final_stages: a study may wrap the module's final_stage)
_PLAIN_FINAL_STAGES = final_stages  # (core.tracking.joint_pipeline.applies: the module's own, by identity)


#: :func:`confirm_move`: the stage run again from another start confirms its pose where it lands
#: within this fraction of the stage's move of it (translation; rotation too, or within 0.05°)
CONFIRM_FRACTION = 0.25


def confirm_move(renderer, frame: FrameImages, res, start=None, *, bone: int, center, options,
                 views: Sequence[int], others=None) -> dict | None:
    """Whether the final stage's pose of ``res`` (a registration result whose pose is the stage's,
    ``likelihood_taken``) is the stage's optimum and not an artefact of where it began (the
    similarity's pose: the region and the robust weights were made about it, and a refinement stops
    at a step the data barely resolve): the stage run again from ``start`` — by default the far side
    of its pose, the similarity's pose mirrored through it (as far from it as the first start, within
    the stage's reach) — with the same options and neighbours, its refinements to ``tol`` (at most
    20 steps each; :data:`~core.tracking.engine_likelihood.TO_TOL`). Returns ``{"mm", "deg", "confirmed"}``
    (the two stage poses' distance; confirmed where it is within :data:`CONFIRM_FRACTION` of the
    first stage's move, translation and rotation, the rotation within 0.05° at least, and the second
    run's move was taken), with the second run's ``evaluations`` and ``time_s``; None where ``res``'s
    pose is not the stage's. :func:`core.tracking.frame_step.track_frame` asks it before a stage move
    the move check flags is rejected (:data:`core.tracking.frame_step.STAGE_MOVE_CONFIRM`). The far
    side is the stage's move applied twice to the similarity's pose (the rotation ``R_d² R_sim``,
    ``R_d = R_stage R_simᵀ``, the centre's image at ``2 c_stage − c_sim``: a composition, not rotation
    vectors subtracted). It tests that the pose does not depend on the start, not that it is
    right: a biased optimum of the stage's cost that both starts reach is confirmed."""
    from .checks import _distance, pose_delta, step_pose

    t = res.timing or {}
    mm, deg = t.get("likelihood_move_mm"), t.get("likelihood_move_deg")
    prior = getattr(getattr(res, "fit", None), "similarity", None)
    if not t.get("likelihood_taken") or mm is None or deg is None or (start is None and prior is None):
        return None
    c = np.asarray(center, dtype=float)
    if start is None:
        start = step_pose(2.0 * pose_delta(prior.pose, res.pose, c), prior.pose, c)
    start = np.asarray(start, dtype=float)
    token = TO_TOL.set(True)  # (to tol: a stop at a step the data barely resolve is no test of the optimum)
    try:
        again = final_stage(renderer, frame, replace(res, pose=start, timing={}), bone=bone,
                            initial_pose=start, center=center, views=views, others=others,
                            options=replace(options, final_iters=max(options.final_iters, 20)))
    finally:
        TO_TOL.reset(token)
    ta = again.timing or {}
    dt, dr = _distance(again.pose, res.pose, c)
    ok = bool(ta.get("likelihood_taken") and dt <= CONFIRM_FRACTION * mm
              and dr <= max(CONFIRM_FRACTION * deg, 0.05))
    return {"mm": float(dt), "deg": float(dr), "confirmed": ok,
            "evaluations": int(again.evaluations - res.evaluations),
            "time_s": float(ta.get("likelihood_s", 0.0))}


#: :func:`stage_prefetch`'s regions: the stage's at the given pose grown by this much more reach (mm;
#: for the search's move from its start, the prediction; the regions are snapped to 16 px). On the
#: benchmark's trial (the talus at 1024², 40 frames, ``stage_one_bone`` on one NVIDIA H100,
#: ``tracking_stage_one_bone_97b2893_h100.json`` and ``_f8d6619_h100.json``) every stage of every run took
#: the prefetched rows (40 of 40); a real trial's moves are not measured.
PREFETCH_REACH_MM = 2.0


def stage_prefetch(renderer, frame: FrameImages, *, bone: int, pose, center, options, views: Sequence[int],
                   reach_mm: float | None = None) -> bool:
    """Upload the fluence of the regions the final stage of ``options`` will need in ``frame`` while
    the search still runs (:meth:`~core.tracking.likelihood_frames._FrameRegions.prefetch`; e.g. in
    :func:`core.tracking.register.register`'s ``idle`` slot, while the device works on the search's
    first step): the stage's regions (:func:`final_stage_steps`) at ``pose`` (the search's start, its
    prediction) grown by ``reach_mm`` more (:data:`PREFETCH_REACH_MM`). The stage then takes them on
    the device where they cover its own regions at the searched pose (the same values; else it uploads
    its own). Returns whether they went up (False: no stage, an outline region, regions the host makes)."""
    from .engine_likelihood import DEVICE_REGIONS

    o = options
    if o.final is None or REGION_OUTLINE is not None or not DEVICE_REGIONS:
        return False
    _, hp = MODEL.for_bone(bone, o.final_highpass_px)
    views = tuple(views)
    extra = PREFETCH_REACH_MM if reach_mm is None else float(reach_mm)
    try:
        roi = snap_roi(search_roi(renderer, np.asarray(pose, dtype=float), bone, views=views,
                                  center=np.asarray(center, dtype=float), reach_mm=1.0 + extra,
                                  margin_px=o.margin_px), renderer, views)
    except OutsideViewError:
        return False
    eng = likelihood_engine(renderer, bone=bone, views=views, highpass_px=hp, lag_px=o.final_lag_px,
                            others_gain=o.final_others_gain)
    return eng.prefetch(frame, roi)


def final_stage_steps(renderer, frame: FrameImages, res, *, bone: int, initial_pose, center, options,
                      views: Sequence[int], others=None, clock: StepClock | None = None,
                      side_by_side: bool = False):
    """:func:`final_stage` as a generator (its value the result) that yields where it would wait
    for the device (:func:`final_stages`); ``clock`` its :class:`~core.tracking.engine_likelihood.
    StepClock` (default: the wall time from the start); ``side_by_side``: the engine keeps its
    own copy of the rendered images (other bones render between its steps)."""
    o = options
    if o.final is None or any(s.reason == "cancelled" for s in res.stages):
        return res
    if others is None:
        others = _NEIGHBOURS.get()
    clock = StepClock() if clock is None else clock
    timing = dict(res.timing)
    views = tuple(views)
    center = np.asarray(center, dtype=float)
    eng = None
    try:
        model, hp = MODEL.for_bone(bone, o.final_highpass_px)
        pts = None if REGION_OUTLINE is None else support_points(renderer, bone)
        grow = 0 if pts is None else int(np.ceil(REGION_OUTLINE * (hp or 0.0)))
        roi = snap_roi(search_roi(renderer, res.pose, bone, views=views, center=center, reach_mm=1.0,
                                  margin_px=o.margin_px + grow, points=pts), renderer, views)
        eng = likelihood_engine(renderer, bone=bone, views=views, highpass_px=hp,
                                lag_px=o.final_lag_px, others_gain=o.final_others_gain)
        eng.timer, eng.renders = CostTimer(), 0
        eng.own_images = bool(side_by_side)
        eng.set_frame(frame, base_pose=res.pose, center=center, roi=roi, others=others)
        if model.rim_sigmas is not None and hp:
            apply_rim(eng, frame, model.rim_sigmas * hp)
        again = _set_tissue(eng, renderer, model, bone, res.pose, others)
        timing["likelihood_setup_s"] = clock.seconds()
        out = yield from _refine_steps(eng, o, model, again)
    except (OutsideViewError, np.linalg.LinAlgError):  # the similarity's pose stands
        timing.pop("likelihood_setup_s", None)  # (a region without usable pixels: seen at the first step)
        timing["likelihood_s"] = clock.seconds()
        timing["likelihood_taken"] = 0
        if eng is None:
            return replace(res, timing=timing)
        # (the regions made on the device: the first step rendered its design before the count was read)
        timing["likelihood_renders"] = int(eng.renders)
        return replace(res, timing=timing, evaluations=res.evaluations + int(eng.timer.evaluations))
    d = np.asarray(out["x"], dtype=float)
    cov = np.asarray(out["covariance_independent" if o.final_confidence == "independent" else "covariance"],
                     dtype=float)
    if o.final_confidence == "sandwich+move":  # the two costs' disagreement: a systematic part neither sees
        cov = cov + np.outer(d, d)
    reach = np.array([o.final_reach[0]] * 3 + [o.final_reach[1]] * 3)
    dt = clock.seconds()
    timing["likelihood_s"] = dt
    timing["likelihood_steps"] = int(out["iterations"])  # (moment tables solved)
    timing["likelihood_renders"] = int(eng.renders)  # (the steps' DRR launches: images reused save some)
    timing["total_s"] = timing.get("total_s", 0.0) + dt
    evals = res.evaluations + int(eng.timer.evaluations)  # (the poses the steps rendered)
    timing["likelihood_move_mm"] = float(np.linalg.norm(d[:3]))  # NaN when the steps failed
    timing["likelihood_move_deg"] = float(np.linalg.norm(d[3:]))
    if not (np.isfinite(d).all() and (np.abs(d) <= reach).all() and np.isfinite(cov).all()):
        timing["likelihood_taken"] = 0
        return replace(res, timing=timing, evaluations=evals, time_s=res.time_s + dt)
    pose = eng.poses(d[None])[0]
    p = stage_params(pose, center, np.asarray(initial_pose, dtype=float))
    x = np.concatenate((p[:3], np.degrees(p[3:])))
    timing["likelihood_taken"] = 1
    fit = LikelihoodFit.of(cov, x=x, chi2=float(out["chi2"]),
                           covariance_independent=out["covariance_independent"], similarity=res)
    return replace(res, pose=pose, x=x, fit=fit, timing=timing, evaluations=evals, time_s=res.time_s + dt,
                   generations=res.generations + int(out["iterations"]))
