"""One bone's next frame's search prepared while the device works on this frame's final stage.

One bone tracked with the final stage (:func:`core.tracking.trial.track`): while the device works on frame
``t``'s stage (:func:`core.tracking.register_ahead.stage_idle`, where the host waits otherwise), frame
``t + 1``'s start is predicted from frame ``t``'s *searched* pose (the pose the stage began from; the
stage's own is not known yet) and the bone's good pose before it, and the search from it is prepared
(:func:`core.tracking.register.prepare_search`: the pixel size, the search regions, the engine's regions of
the next frame, read by the feed's worker meanwhile). At frame ``t + 1``, where the bone's good history is
what the prediction assumed (frame ``t`` good and added, the same frame before it),
:func:`core.tracking.frame_step.track_frame` starts the search from that prediction (:func:`start`) and the
registration takes what was prepared; the motion check still judges the frame against the
constant-velocity prediction from the final poses. The start differs from the serial loop's by about
twice frame ``t``'s stage move; the search and the stage after it then end within their tolerances of
the serial loop's poses (not to the bit). :data:`SEARCH_AHEAD` switches it on.
"""

from __future__ import annotations

import numpy as np

from .frame_state import motion_prediction, predict_pose

__all__ = ["SEARCH_AHEAD", "prepare", "start"]

#: Prepare one bone's next frame's search during this frame's final stage, from this frame's searched
#: pose (module docs); off: the serial loop (the start from the final poses, prepared at its turn). Not
#: timed on a GPU.
SEARCH_AHEAD = False


def prepare(run, state: dict, feed, f: int, f_next: int, res):
    """A generator for :func:`~core.tracking.register_ahead.stage_idle`: frame ``f_next``'s start from
    frame ``f``'s searched pose (``res.pose``) and the search from it prepared, in two pieces (module
    docs); its record in ``run.ahead[f_next]`` (where it was prepared)."""
    o = run.options
    if o.guess != "velocity" or len(run.names) != 1:
        return
    b, bone = run.names[0], run.bones[0]
    hist = state[b].history
    kf = (run.keyframes.get(b) or {}).get(f_next)
    a = feed.ahead
    if not hist or kf is not None or a is None or a[0] != f_next or not a[2].done():
        return
    if a[2].exception() is not None or a[2].result() is None:
        return
    frame = a[2].result()
    h = [hist[-1], (int(f), np.asarray(res.pose, dtype=float))]
    guess = predict_pose(h, f_next, bone.centroid, guess=o.guess, prediction=motion_prediction(h, f_next,
                                                                                               bone.centroid))
    yield
    from .register import prepare_search

    if prepare_search(run.renderer, frame, bone=0, pose=guess, center=bone.centroid, options=o.registration,
                      outline=bone.outline):
        f0, T0 = hist[-1]
        run.ahead[f_next] = (int(f0), np.asarray(T0, dtype=float).tobytes(), int(f), len(hist), guess)


def start(run, state: dict, f: int, i: int):
    """Frame ``f``'s start for bone ``i`` prepared by :func:`prepare` where the bone's good history is what
    it assumed (the frame before added as good, the same pose before that), else None; taken once."""
    rec = run.ahead.pop(f, None) if run.ahead else None
    if rec is None or len(run.names) != 1:
        return None
    run.ahead.clear()
    f0, T0, f1, n, guess = rec
    hist = state[run.names[i]].history
    if len(hist) != n + 1 or hist[-1][0] != f1 or hist[-2][0] != f0 or hist[-2][1].tobytes() != T0:
        return None
    return np.array(guess, dtype=float)
