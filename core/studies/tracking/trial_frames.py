"""The acceptance trial's frames made in worker processes (:func:`synthesise`): the line integrals
on the scene's renderer in this process, the image chain (noise, blur, distortion, flatfield,
unwarp) of each frame in a forked worker. The frames are those of
:meth:`core.studies.tracking.acceptance.TrackingScene.frames` (the same per-frame seeds), made
several at a time."""

from __future__ import annotations

import numpy as np

__all__ = ["synthesise"]

_POOL_SCENE: list = []

#: Seconds a frame may take in a worker before :func:`synthesise` gives up (``multiprocessing.TimeoutError``).
WORKER_TIMEOUT_S = 900.0


def _chain_frame(args):
    """One frame through the trial's image chain (the body of ``TrackingScene.frames``): the raw
    frames (when the scene keeps them) and the corrected ones."""
    ts, i, L = _POOL_SCENE[0], args[0], args[1]
    sc = ts.scene
    raw = np.stack([m.apply(L[v], rng=sc.frame_rng(i, v)) for v, m in enumerate(sc.imaging)])
    return i, (raw if ts.raw is not None else None), [ts.correct(v, f) for v, f in enumerate(raw)]


def synthesise(ts, frames, workers: int = 0) -> None:
    """Fill ``ts``'s frame cache (a ``TrackingScene``; the same frames as its ``frames(i)``) for
    ``frames`` not made yet, the image chain in ``workers`` forked processes (0 or 1: in this
    process, one frame at a time)."""
    todo = [i for i in frames if i not in ts._cache]
    if workers <= 1:
        for i in todo:
            ts.frames(i)
        return
    import multiprocessing as mp

    _POOL_SCENE[:] = [ts]
    try:
        with mp.get_context("fork").Pool(workers) as pool:
            jobs = []
            for i in todo:
                L = ts.scene.line_integrals(i, renderer=ts._scene_renderer)
                jobs.append(pool.apply_async(_chain_frame, ((i, L),)))
            for j in jobs:  # a forked worker stuck on a lock copied from a busy thread: an error, not a hang
                i, raw, imgs = j.get(timeout=WORKER_TIMEOUT_S)
                ts._cache[i] = imgs
                if raw is not None:
                    ts.raw[i] = raw
    finally:
        _POOL_SCENE.clear()
