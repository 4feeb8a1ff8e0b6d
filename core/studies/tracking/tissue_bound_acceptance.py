"""The acceptance study's bound with the soft tissue unknown (:func:`acceptance_bound`), reported beside the
known-tissue one by :mod:`core.studies.tracking.acceptance`; kept apart from
:mod:`core.studies.tracking.tissue_bound` (the study of the bounds of several tissue models, which builds the
acceptance scene itself) so that the acceptance study and that study do not import each other."""

from __future__ import annotations

import time
import weakref

import numpy as np

__all__ = ["ACCEPTANCE_SPACING_MM", "MIN_SPACING_PX", "acceptance_bound", "add_acceptance_bound", "summary"]

#: The tissue-unknown bound the acceptance study reports beside the known-tissue one
#: (:func:`acceptance_bound`): cubic B-splines every 4.6875 mm at the isocentre (4 px of a 256² view, 16 px
#: of a 1024² one: ``bs4``, the one spacing of :data:`core.studies.tracking.tissue_bound.SPACINGS_256`
#: whose efficient estimator's bias from this trial's tissue stays within its bound) plus the bone's gain,
#: per view.
ACCEPTANCE_SPACING_MM = 4.6875

#: :func:`acceptance_bound` needs its knots at least this many pixels apart (a field about as fine as the
#: pixels imitates the bone itself, and its thousands of parameters cost minutes): views coarser than
#: that (test scenes of 64²–80²: 1–1.3 px) have none.
MIN_SPACING_PX = 2.0


def acceptance_bound(ts, frames) -> dict:
    """Per bone of the acceptance scene ``ts``: its Cramér–Rao bound with the soft tissue and walkway
    unknown (:func:`core.tracking.bound_nuisance.nuisance_bounds`; model :data:`ACCEPTANCE_SPACING_MM`),
    mean covariance over ``frames`` as :func:`~core.studies.tracking.acceptance.cramer_rao` averages the
    known-tissue one: ``rms_mm``, ``rms_deg``, ``sigma``, ``ratio_to_known`` (over the known-tissue bound
    of the same frames and derivatives), ``model``, ``spacing_px``, ``frames``, ``time_s``. Empty when
    the frames are noise-free or the views too coarse (knots under :data:`MIN_SPACING_PX` apart); a bone
    seen in no frame, or whose bound is singular in every frame, has none."""
    from core.tracking.bound_nuisance import nuisance_bounds
    from core.tracking.cost import OutsideViewError

    N = [m.photons_per_pixel for m in ts.scene.imaging]
    if any(n is None for n in N):
        return {}
    t0 = time.perf_counter()
    spacing = ACCEPTANCE_SPACING_MM / float(ts.scene.rig[0].pixel_size)
    if spacing < MIN_SPACING_PX:
        return {}
    mods = {"bs": {"basis": "spline", "spacing_px": spacing, "gain": True}}
    known = {n: [] for n in ts.names}
    cov = {n: [] for n in ts.names}
    used = {n: [] for n in ts.names}
    for f in (int(f) for f in frames):
        L = ts.scene.line_integrals(f, renderer=ts._scene_renderer)
        for b, (n, m) in enumerate(zip(ts.names, ts.models, strict=True)):
            try:
                nb = nuisance_bounds(ts.renderer, b, ts.truth(f)[b], m.centroid, mods, line_integral=L,
                                     quanta_per_pixel=N)["bs"]
            except OutsideViewError:  # the bone left both views: no bound in that frame
                continue
            if np.all(np.isfinite(nb.nuisance.covariance)) and np.all(np.isfinite(nb.known.covariance)):
                known[n].append(nb.known.covariance)
                cov[n].append(nb.nuisance.covariance)
                used[n].append(f)
    out = {}
    model = (f"cubic B-spline field per view, knots every {ACCEPTANCE_SPACING_MM:g} mm at the isocentre, "
             "plus the bone's gain (core.tracking.bound_nuisance)")
    for n in ts.names:
        if not cov[n]:
            continue
        K, S = summary(np.mean(known[n], axis=0)), summary(np.mean(cov[n], axis=0))
        ratio = {"mm": S["rms_mm"] / K["rms_mm"], "deg": S["rms_deg"] / K["rms_deg"]}
        out[n] = {**S, "ratio_to_known": ratio, "model": model, "spacing_px": spacing, "frames": used[n]}
    for v in out.values():
        v["time_s"] = time.perf_counter() - t0  # all bones' together
    return out


_SCENE_BOUNDS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def add_acceptance_bound(ts, bound: dict, frames) -> None:
    """Add to each bone of ``bound`` (:func:`~core.studies.tracking.acceptance.cramer_rao`'s, of
    ``frames``) its tissue-unknown bound (:func:`acceptance_bound`) as ``tissue_unknown``, computed once
    per scene and frames (the modes of one acceptance call share it)."""
    key = tuple(int(f) for f in frames)
    per_scene = _SCENE_BOUNDS.setdefault(ts, {})
    if key not in per_scene:
        per_scene[key] = acceptance_bound(ts, key)
    for n, tb in per_scene[key].items():
        if n in bound:
            bound[n]["tissue_unknown"] = dict(tb)


def summary(C: np.ndarray) -> dict:
    """RMS translation (mm) and rotation (°) of a 6×6 pose covariance, and its axes' σ."""
    return {"rms_mm": float(np.sqrt(np.trace(C[:3, :3]))), "rms_deg": float(np.sqrt(np.trace(C[3:, 3:]))),
            "sigma": np.sqrt(np.diag(C)).round(5).tolist()}
