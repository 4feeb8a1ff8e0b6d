"""The restart check's first pyramid level prepared while the checked registration's final stage runs.

A first frame (and a retry) is registered by the global search and then checked by restarts
(:func:`core.tracking.verify.verify_start`): with the Gauss–Newton searches these run side by side
(:func:`core.tracking.joint.restarts_together`) from one search box about the checked pose, half
resolution first, and their first act is that level's host pyramid of the box's regions
(:func:`core.tracking.engine_frames.pyramid_rois`: a low-pass and sampling of each view's region, about a
millisecond per view and level on a GPU machine's host). :func:`restart_regions_ahead` has those regions
prepared in the view threads (:func:`~core.tracking.engine_frames.pyramid_ahead`) while the device works
on the registration's final stage, from the pose the search ended at: the stage moves it by hundredths of
a millimetre, so the restart check's box about the stage's pose is most often the same box, and where it
is, its level takes the regions prepared (the same function on the same inputs: the same arrays); where the
stage moved a region's edge across a pixel, the level prepares its own as before (the same results either
way). :data:`RESTART_REGIONS_AHEAD` switches it.

Measured and left off: on this 2-core x86_64 machine the bench's one-bone trial's first frame at 1024²
(``python -m core.studies.tracking.first_host --pixels 1024 --voxel 2 --rounds 3``, the talus on Warp's
CPU device; ``resources/benchmarks/tracking_first_host_restarts_cpu.json``) found the restarts' box about
the stage's pose different from the one about the searched pose in all three runs (pixels of 0.3 mm at the
bone: the stage's move of hundredths of a millimetre moved an edge of an unsnapped box across a pixel),
so the restarts prepared their own regions every time; at 512² (the levels of 1024² kept, ``--coarsest
2.5``) and in the tests at 128² the restarts took them.
"""

from __future__ import annotations

from contextlib import contextmanager
from dataclasses import replace

import numpy as np

__all__ = ["RESTART_REGIONS_AHEAD", "restart_level", "restart_regions_ahead"]

#: The restart check's first pyramid level prepared during the checked registration's final stage (off: module
#: docs, *Measured*).
RESTART_REGIONS_AHEAD = False


def restart_level(renderer, frame, pose, center, options, spread, views) -> tuple | None:
    """``(search options, first level's scale)`` of :func:`core.tracking.verify.verify_start`'s
    side-by-side restarts about ``pose`` (as it makes them from the tracker's registration ``options``
    and ``spread``), or None where its restarts are not the Gauss–Newton ones."""
    from .register import _newton_fallback, mm_per_pixel
    from .verify import _engine_supports

    o = options
    if not (o.search in ("newton", "global_newton") and o.levels is None and o.refine is None
            and _engine_supports(o.terms)):
        return None
    o = replace(o, search="newton", levels=None,
                bounds=(max(o.bounds[0], 2 * spread[0]), max(o.bounds[1], 2 * spread[1])))
    fs = o.final_scale
    first = _newton_fallback(mm_per_pixel(renderer, np.asarray(pose, float), np.asarray(center, float),
                                          views) * fs)[0]
    return o, first.scale * fs


def restart_regions_ahead(renderer, frame, pose, *, bone: int, center, options, spread, outline=None) -> None:
    """The restart check's first level's regions about ``pose`` prepared in the view threads now
    (module docs); nothing where that level is not a pyramid level."""
    from .engine_frames import pyramid_ahead
    from .register import search_region

    views = tuple(range(frame.n_views))
    got = restart_level(renderer, frame, pose, center, options, spread, views)
    if got is None or not got[1] > 1:
        return
    o, scale = got
    from .cost import OutsideViewError

    try:
        roi = search_region(renderer, np.asarray(pose, dtype=float), bone, views=views,
                            center=np.asarray(center, dtype=float), options=o, outline=outline)
    except OutsideViewError:
        return
    pyramid_ahead(frame, views, roi, scale)


@contextmanager
def during_stage(renderer, frame, *, bone: int, center, options, spread, outline=None):
    """Within the block, the registration's final stage (:func:`core.tracking.register_ahead.stage_idle`'s
    slot) also prepares the restart check's regions about the searched pose (:func:`restart_regions_ahead`),
    after the work the slot held (taken from the caller's slot as the stage would take it)."""
    from .register_ahead import _STAGE_IDLE, stage_idle

    if not RESTART_REGIONS_AHEAD:
        yield
        return
    outer = _STAGE_IDLE.get()

    def work(res):
        fn = outer.pop() if outer else None
        out = fn(res) if fn is not None else None
        restart_regions_ahead(renderer, frame, res.pose, bone=bone, center=center, options=options,
                              spread=spread, outline=outline)
        return out

    with stage_idle(work):
        yield
