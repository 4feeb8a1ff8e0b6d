"""The first tracked frame registered once more, backward from the frames after it
(:func:`backward_check`), once a :func:`core.tracking.trial.track` run is complete.

A bone's first frame is registered unlike the others: from a hand-placed keyframe (the acceptance
study's 5 mm / 5° off), with the first frame's widened options, a global search, the restart check and
a second round or pass. The frames after it are registered from the constant-velocity prediction of
the frames before them. Two things leave a wrong first frame unseen. The per-frame checks judge a
frame against the bone's own history, which a first frame does not have; and the trajectory
post-pass (:mod:`core.tracking.flags_post`) judges it only by extrapolating the fit through the
frames after it, which divides its residual by ``sqrt(1 + leverage)``: about 3 for the parabola
through frames 1-4. Seed 4's tibia at frame 0 (one NVIDIA H100, 1024², c7320cb,
``resources/benchmarks/tracking_acceptance_seed4_final_c7320cb_h100.json``) was 0.72° off (−0.69°
about its long axis, 6.3× its bound) in both modes, its neighbours −0.15° to −0.29° about that axis;
jointly the parabola through frames 1-4 missed it by 0.304° about z, 0.110° normalised, 1.12× the
bone's median (the limit 2.5×); sequentially frame 2 was flagged and it was left unchecked. Rules
from the trajectory alone barely separate it: judged against the bone's own frames fitted alike (the
same one-sided fit, as the gap rule of :mod:`core.tracking.flags_post` scales its frames; the c7320cb
runs of seeds 0, 3 and 4, both modes, 18 first frames), in rotation the parabola through the next 4
frames put it at 1.58× and 1.44× their median (good first frames up to 2.35×), the parabola through 6 at
2.53× and 2.59× (up to 2.94×), the line through 2 at 2.23× and 2.33× (up to 2.28×) and only the line
through 3 apart, 2.59× and 2.71× against at most 2.07×; in translation good first frames reached 5.5×,
the truth itself missing such fits by up to 5.1× the median (the walking motion accelerates at the
trial's start). These ratios come from an exploratory computation not kept in the
repository; a re-computation with the gap rule's scaling gave other ratios (the parabola through 4:
0.87× and 0.93× against good first frames up to 1.66×; the line through 2: 2.22× and 2.32× against up to
1.89×; translation up to 2.25×) and the same conclusion.

So the check asks the images instead: after the forward pass, the first frame of each bone is registered
again as the tracker registers every other frame — the frame step of
:func:`core.tracking.frame_step.track_frame`, from the run's guess (``TrackingOptions.guess``) from the
bone's good frames after it — the constant-velocity prediction of the nearest two by default, the pose
of the nearest with ``"previous"``, the spline through the bone's other keyframes with ``"spline"``
where they lie on both sides of it (the note names which) — the history (guesses, scores, σ, stage
moves) those frames and the ones after them make when taken in reverse order, the neighbours subtracted
as in any later frame (the first frame's keyframes are not used: the registration is the frame step's,
not the first frame's) — and the two registrations are compared. Where they disagree by more than
``TrackingOptions.backward_limit`` (default :data:`LIMIT`) × the bone's median
trajectory residual (:func:`core.tracking.flags_post.trajectory_residuals`, the trajectory check's
scale, over the run's good frames; at least :data:`FLOOR`) in translation or rotation, the first frame
is flagged (:data:`FLAG`, with both distances and the limits); otherwise it gets the note :data:`NOTE`
with the distance. A bone with fewer than :data:`~core.tracking.flags_post.MIN_FRAMES` trajectory
residuals (a short run) has no scale and is not judged (the note gives the distance): the backward
registration carries the errors of the frames it is predicted from (on the ideal 128² talus-calcaneus
scene from true keyframes, the talus's third frame 0.24° off left it 0.23° from a first frame 0.003°
off). The first frame's pose is kept either way: two registrations that disagree do not tell which is
right (the backward one carries the errors of the frames it was predicted from), so the frame is sent
for review. A backward registration that is itself flagged, or has no pose, judges nothing (a note says
so); a bone with fewer than two good frames among the :data:`REACH` tracked frames after its first, or
whose first frame is flagged already or was given as a pose, is not checked (one given as a pose, a hand
fix taken back on resume, is subtracted at it as the forward pass did).

The flag is a review flag, as the trajectory post-pass's: the registration's ``converged`` stays as
it was, and :class:`core.tracking.frame_state._BoneState` takes a frame restored with it (resume) as
the run that made it did. Frames that carry an earlier check's flag or note are judged afresh (those
taken off first), so a resumed run that completes gives the flags of an uninterrupted one: the
backward registration is seeded from its frame number, as every registration is. It costs one
frame's registration per run (its evaluations and seconds go into the frame's ``timing`` as
``backward_evaluations`` and ``backward_s``, not into its ``evaluations``) and runs before the
trajectory post-pass, which then neither judges a flagged first frame nor fits through it.
``TrackingOptions.backward_limit=None`` turns it off. A run over a range checks the range's first frame
in tracking order (a backward range's highest frame) from its own side only: a keyframe that two
ranges of ``talus batch`` both track is checked by each, its journal keeping the outcome of the range
recorded last and each range's report its own. Once every range has run, the batch's pass
(:func:`core.tracking.batch.trajectory_pass`, :mod:`core.tracking.batch_pass`) gives the frame both
ranges' flags and notes of this check, the ranges in frame order (the backward one first), and in its
``timing`` their backward registrations added up (``backward_ranges`` says how many), in the journal
and both reports — whether or not a range flagged it, with the trajectory check on or off and with a
range of the group not complete (then only the keyframe is merged), wherever two of the ranges'
reports can be read — so, as the trajectory flags (:mod:`core.tracking.batch`'s notes), the frame's
flag, notes and timing do not depend on the order the tasks ran.

*Measured* (``resources/benchmarks/tracking_backward_check_h100.json``): the acceptance study on seeds
0, 3 and 4 (``--mode joint,sequential --final likelihood``, 1024², 100 frames) at 8536510, one NVIDIA
H100, the check's limit then 2.5× the median (the trajectory check's): every pose as at c7320cb (the
per-frame errors equal to the digits kept), no first frame flagged. The 18 first frames' backward
registrations landed 0.001-0.015 mm and 0.006-0.165° from the forward ones (52 or 39 evaluations, 5-9
ms). In units of the bone's median residual the two over 4× their bound, seed 4's tibia, stood 1.46×
(jointly, 0.143°) and 1.72× (sequentially, 0.165°) in rotation, the 16 good ones at most 1.00× (seed 3's
tibia, 0.080° in both modes; the rest ≤ 0.41×): the frame step from the backward prediction (about
−0.25° about the tibia's long axis, frames 1 and 2 carrying that error) goes most of the way back to the
forward pose, 0.69° off: the first frame's error is mostly its image's optimum, not its registration
path (the backward pose was not kept; 0.143° from a pose 0.72° off, it is itself at least 0.57° off), so
neither pose would do and the flag keeps the forward one. :data:`LIMIT` 1.25 lies between the two
groups, chosen on these runs (no held-out run has judged it): with it, computed from the same run's
distances and the trajectory post-pass run again on the rebuilt poses (this 2-core x86_64 CPU), seed 4's
tibia frame 0 is flagged in both modes (silent frames over 4× jointly 2 → 1 of the tibia's, frame 7
left; sequentially 1 → 0), no good first frame is; the post-pass then flags the tibia's frame 61 jointly
(its median 0.098° → 0.095° without frame 0) and no longer its frame 2 sequentially; seeds 0 and 3
unchanged.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .checks import _distance
from .flags_post import BACKWARD_FLAG, MIN_FRAMES, trajectory_residuals
from .flags_post import FLAG as TRAJECTORY_FLAG
from .frame_state import _BoneState
from .frame_step import track_frame
from .options import BACKWARD_LIMIT
from .register_ahead import stage_idle
from .results import FrameResult

__all__ = ["FLAG", "FLOOR", "LIMIT", "NOTE", "REACH", "SCALE_AHEAD", "backward_check"]

#: The checked bones' trajectory scales (:func:`_scale`, a local fit through each of the run's good frames:
#: 2.6 ms for 100 frames on this 2-core x86_64 machine) computed while the device works on the backward
#: registration's final stage (one bone's: :func:`core.tracking.register_ahead.stage_idle`), where the host
#: would wait, instead of after it; computed after it where no such wait came (joint registration, no final
#: stage). The same values: they read the forward run's results, which the registration does not change.
SCALE_AHEAD = True

#: The flag's name (:data:`core.tracking.flags_post.BACKWARD_FLAG`; the message starts with it).
FLAG = BACKWARD_FLAG
#: The note of a first frame checked and not flagged, or not judged (the message starts with it).
NOTE = "first frame registered again backward"
#: A first frame whose backward registration lands more than this many times the bone's median trajectory
#: residual away (translation or rotation) is flagged (module docs, *Measured*: chosen on those runs): the
#: default of ``TrackingOptions.backward_limit`` (:data:`core.tracking.options.BACKWARD_LIMIT`), which
#: the check uses (None: the check off).
LIMIT = BACKWARD_LIMIT
#: The two good frames the backward prediction starts from lie within this many tracked frames after
#: the first.
REACH = 4
#: The smallest disagreement (mm, degrees) that is flagged: :data:`core.tracking.frame_step.CONFIRM_FLOOR_MM`
#: and the stage confirmation's 0.05° (:func:`core.tracking.final_stage.confirm_move`).
FLOOR = (0.02, 0.05)


def _own(fr):
    """``fr`` without this check's flag and note."""
    flags = tuple(s for s in fr.flags if not s.startswith(FLAG))
    notes = tuple(s for s in fr.notes if not s.startswith(NOTE))
    t = {k: v for k, v in (fr.timing or {}).items() if not k.startswith("backward_")}
    if flags == fr.flags and notes == fr.notes and t == (fr.timing or {}):
        return fr
    return replace(fr, flags=flags, notes=notes, timing=t if fr.timing is not None else None)


def _scale(results, order, name, center):
    """The bone's median trajectory residual (mm, degrees) over its good frames of the run (the
    post-passes' flags of a restored frame not counted, as the uninterrupted run had none yet), or None
    with fewer than :data:`~core.tracking.flags_post.MIN_FRAMES` residuals."""
    fs = [f for f in order if (fr := results.get((name, f))) is not None and fr.pose is not None
          and not [x for x in fr.flags if not x.startswith((FLAG, TRAJECTORY_FLAG))]]
    if len(fs) < MIN_FRAMES:
        return None
    R = trajectory_residuals(fs, np.array([results[(name, f)].pose for f in fs]), center)
    R = R[np.isfinite(R).all(axis=1)]
    return np.median(R, axis=0) if len(R) >= MIN_FRAMES else None


def _source(guess: str, keyframes: dict, f0: int, f1: int, f2: int) -> str:
    """The backward registration as the note and flag name it: where the frame step started it
    (:func:`core.tracking.frame_state.predict_pose` with the run's ``guess``, the bone's
    ``keyframes`` without ``f0``'s own and its history of the frames after ``f0``, ``f1`` the
    nearest and ``f2`` the next)."""
    ks = sorted(keyframes or {})
    if guess == "spline" and len(ks) >= 2 and ks[0] <= f0 <= ks[-1]:  # predict_pose's spline
        knots = ", ".join(map(str, ks)) if len(ks) <= 4 else f"{ks[0]}, {ks[1]}, ..., {ks[-1]}"
        return f"its registration from the spline guess through keyframes {knots}"
    if guess == "previous":
        return f"its registration from the pose of frame {f1}"
    return f"its registration from the constant-velocity prediction of frames {f1} and {f2}"


def applies(order, options) -> bool:
    """Whether a complete run over ``order`` with ``options`` runs the check (it may still find no bone to
    register)."""
    return len(order) >= 3 and options.backward_limit is not None


def backward_check(run, feed, order, results: dict, skip: dict, step=track_frame) -> list:
    """Register the first frame of ``order`` again from the frames after it (module docs) and flag or
    note each checked bone's result in ``results`` ((bone, frame) -> FrameResult, updated in place);
    returns the results whose flags, notes or timing changed. ``run``: the
    :class:`~core.tracking.frame_state._Run`; ``feed``: the run's
    :class:`~core.tracking.feed.FrameFeed` (the frame is read again); ``skip``: the run's given frames
    (bone -> {frame: pose or FrameResult}); ``step``: the run's frame step
    (:func:`~core.tracking.frame_step.track_frame`). Nothing changes when the backward registration is
    cancelled."""
    if not applies(order, run.options):
        return []
    f0, names, o = order[0], run.names, run.options
    limit = float(o.backward_limit)
    base, todo, state, skip2 = {}, [], {b: _BoneState() for b in names}, {b: {} for b in names}
    for i, b in enumerate(names):
        fr = results.get((b, f0))
        given = skip.get(b, {}).get(f0)
        if fr is None and given is not None and not isinstance(given, FrameResult):
            # given as a pose (a hand fix taken back on resume): a good pose of the frame, subtracted
            # at it as the forward pass had it (track adds it to the history before the frame step)
            skip2[b] = {f0: given}
            state[b].add_good(f0, given, None)
            continue
        if fr is None or fr.pose is None:
            continue
        base[i] = _own(fr)
        skip2[b] = {f0: base[i]}  # a bone not checked: subtracted at its forward pose
        if [x for x in base[i].flags if not x.startswith(TRAJECTORY_FLAG)]:  # flagged already (the
            continue  # trajectory post-pass's flag of a restored frame comes after, judged afresh)
        after = []  # the bone's frames after the first, nearest first, as the forward pass kept them
        for f in order[1:]:
            got = results.get((b, f))
            if got is None:
                got = skip.get(b, {}).get(f)
            if got is not None:
                after.append((f, got))
            if len(after) >= o.history:
                break
        for f, got in reversed(after):
            if isinstance(got, FrameResult):
                state[b].add(f, got)
            else:  # a given pose: good
                state[b].add_good(f, got, None)
        near = set(order[1:1 + REACH])
        if len(state[b].history) >= 2 and {state[b].history[-1][0], state[b].history[-2][0]} <= near:
            todo.append(i)
            skip2[b] = {}
    changed = {}
    for i, fr in base.items():  # an earlier check's flag and note taken off (judged afresh below)
        if fr is not results[(names[i], f0)]:
            changed[i] = fr
    if todo:
        # the first frame's keyframes are not the frame step's: the checked bones start from their
        # predictions, and their neighbours are subtracted at their guesses, as in any later frame
        kf = {b: {k: v for k, v in (run.keyframes.get(b) or {}).items()
                  if k != f0 or names.index(b) not in todo} for b in names}
        imgs, frame = feed.get(f0)
        scales: dict = {}

        def ahead(res) -> None:  # (SCALE_AHEAD: the forward results only)
            for i in todo:
                scales[i] = _scale(results, order, names[i], run.bones[i].centroid)

        with stage_idle(ahead if SCALE_AHEAD else None):
            new = step(replace(run, keyframes=kf), f0, imgs, frame, todo, state, skip2)
        if new is None:  # cancelled: as the forward pass left it
            return []
        for i in todo:
            b, fr, back = names[i], base[i], new.get(i)
            c = run.bones[i].centroid
            f1, f2 = state[b].history[-1][0], state[b].history[-2][0]
            src = _source(o.guess, kf[b], f0, f1, f2)
            if back is None or back.pose is None or back.flags:
                why = "; ".join(back.flags) if back is not None and back.flags else "no pose"
                fr = replace(fr, notes=(*fr.notes, f"{NOTE}: not judged, {src} flagged ({why})"))
            else:
                dt, dr = _distance(fr.pose, back.pose, c)
                s = scales[i] if i in scales else _scale(results, order, b, c)
                if s is None:
                    fr = replace(fr, notes=(*fr.notes, (
                        f"{NOTE}: not judged ({dt:.3f} mm, {dr:.3f} deg from {src}; fewer than "
                        f"{MIN_FRAMES} of the bone's frames with a trajectory residual to scale it)")))
                else:
                    lim = np.maximum(limit * s, FLOOR)
                    msg = (f"({dt:.3f} mm, {dr:.3f} deg from {src}; limits {lim[0]:.3f} mm, {lim[1]:.3f} "
                           f"deg, {limit:g} x the bone's median trajectory residual {s[0]:.3f} mm, "
                           f"{s[1]:.3f} deg)")
                    if dt > lim[0] or dr > lim[1]:
                        fr = replace(fr, flags=(*fr.flags, f"{FLAG} {msg}"))
                    else:
                        fr = replace(fr, notes=(*fr.notes, f"{NOTE} {msg}"))
            if back is not None:
                fr = replace(fr, timing={**(fr.timing or {}), "backward_evaluations": int(back.evaluations),
                                         "backward_s": float(back.time_s)})
            changed[i] = fr
    out = []
    for i, fr in changed.items():
        key = (names[i], f0)
        old = results[key]
        if fr.flags != old.flags or fr.notes != old.notes or fr.timing != old.timing:
            results[key] = fr
            out.append(fr)
    return out
