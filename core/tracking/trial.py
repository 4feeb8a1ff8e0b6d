"""Whole-trial tracking: many bones over a frame range, saved frame by frame, resumable.

:func:`track` registers every bone in every frame of ``frames`` (in the given order: forward,
backward, or any list), frame-major (all bones of a frame, then the next), and hands each
finished (bone, frame) to ``record`` at once — with a :class:`core.study.Trial` that is
:meth:`~core.study.Trial.record_pose`, which makes the frame durable before tracking goes on.
:func:`track_study` wires a study trial in (frames, rig, bone CTs, journal, report).

Initial guess of a frame (``guess``)
------------------------------------
* ``"previous"`` — the bone's last good pose;
* ``"velocity"`` — constant velocity from the last two good poses (centre displacement and
  rotation vector about the centroid, scaled by the frame gaps), ``"previous"`` with one;
* ``"spline"`` — a cubic spline through the user's keyframes (6 parameters about the first
  keyframe); ``"velocity"`` outside the keyframes' span or with fewer than 2 keyframes.
The first frame of a bone starts from its keyframe at that frame, else the nearest keyframe
(the study journal's poses recorded before tracking act as keyframes), and is registered with
the widened first-frame options.

Bones (``mode``)
----------------
``"sequential"`` (the default) registers each bone alone, against the whole image (its neighbours'
projections left in: on the acceptance trial they biased the tibia about its long axis, up to 0.6°,
and the talus; ``sequential_subtract`` subtracts the neighbours' DRRs in the search, for matched
intensities only: True, or None where :func:`core.tracking.from_study.track_study` finds the frames
flatfield-corrected, see :mod:`core.tracking.frame_step`); ``"auto"`` is joint where
:func:`core.tracking.from_study.track_study` finds the frames flatfield-corrected and sequential
otherwise (:func:`track` itself, which cannot tell, takes it as sequential); ``"joint"`` runs
``joint_rounds`` rounds
in which each bone is registered with the other bones' DRRs (at their latest estimates)
subtracted from the fluoroscope images, so overlapping projections do not pull a bone towards
its neighbour. Subtraction needs DRR intensities matched to the frames (flatfield-corrected
frames, a calibrated HU transfer — true of the synthetic scenes; on the wrist sample's 8-bit
radiographs it pulled the radius into the hole left where the ulna was subtracted), so
:func:`track` does not assume it; :func:`core.tracking.from_study.track_study` tracks the bones of
flatfield-corrected frames jointly when no options are given, with DRRs of each bone's
attenuation in excess of the soft tissue (:func:`core.tracking.from_study.tissue_excess_transfer`).
With the Gauss–Newton search (``registration.search == "newton"``) and ``lockstep`` (the
default; not with ``contact``) the bones of a round that start from a guess are registered side
by side (:func:`core.tracking.joint.register_together`: their steps enqueued together, one
synchronisation per iteration), each with its neighbours subtracted at the poses the round
started from; a bone's first frame (its global search and restart check) is registered alone.
On the 512² foot demo (60 frames, its true calibration, one H200,
``resources/benchmarks/calibration_tracking_h200.json``) one bone at a time lost the talus
between the tibia and the calcaneus (6.0 mm / 4.9° RMS with the plain thresholded transfer,
2.2 mm / 3.1° with the tissue-excess one); jointly, with the tissue-excess transfer, it was
within 0.07 mm / 0.36° and the tibia and calcaneus within 0.04–0.06 mm / 0.18–0.27°.
On the synthetic walking trial (tibia, talus,
calcaneus, 1024², 100 frames, H200, GC on a fluoroscope smoothed by 1 px) joint tracking
lowered the per-frame rotation errors from 0.23/0.34/0.17° to 0.20/0.28/0.15°
(tibia/talus/calcaneus) for about twice the time; with the default cost (both images
smoothed alike) joint tracking gave 0.18/0.27/0.14°
(``resources/benchmarks/tracking_cost_study_h200.json``).

Bones that touch (``contact``)
------------------------------
Overlapping bones can trade image evidence in joint mode: the talus, between the tibia and the
calcaneus, may slide into a neighbour where their edges line up. With ``contact=True`` every
joint registration whose pose comes closer than ``contact_margin_mm`` to a neighbour already
registered in that frame (signed surface distance of :mod:`core.tracking.contact`) is
polished under the image cost plus ``contact_weight`` × the squared interpenetration depth
(mm²), and the frame notes the depth resolved. The constraint's curvature enters that frame's
confidence.

Filtered trajectories
---------------------
Per-frame registrations carry independent noise (~0.2° in rotation at thesis-like dose; the
Cramér–Rao bound of :mod:`core.tracking.bound` shows that no single-frame estimate of a talus
(unbiased) gets below ~0.16° RMS at that dose); bone motion is smooth.
:meth:`TrackingResult.filtered_poses` low-passes a bone's poses with the zero-phase Butterworth
filter of :mod:`core.tracking.kinematics`, its cut-off from Winter's residual analysis of the
centroid path unless given: the kinematics users analyse.

Failure detection and review flags
----------------------------------
A registration fails when it did not converge (or hit the search box), when its score falls below
``min_score_ratio`` × the median of the bone's last ``history`` good scores, or below
``min_start_ratio`` × the score of its verified first frame while every recent good score is above
that floor (a floor that a slow drift into a false optimum cannot move), when it collapses below
:data:`~core.tracking.checks.COLLAPSE_RATIO` × the recent median, or when it jumps more than
``max_jump`` (mm, degrees) from the initial guess (``retry_factor`` × that on a bone's first frame,
which starts from a hand-placed pose; times the good poses' spacings a guess extrapolates over
after flagged frames). A failed frame is retried once with ``retry_factor``× wider
bounds and steps and a global first stage (from the guess and from the last good pose); the best
retry is kept, and if it still fails the frame is recorded *flagged for review* with its reasons and
is not used for later guesses. A frame whose only failure is the relative score drop is not flagged
when the best retry ends within :data:`SAME_OPTIMUM` of its first registration and the
``verify_restarts`` restarts from it (:func:`core.tracking.verify.verify_start`) find no better
score: the image changed (a bone moving behind its neighbours, out of the beam's centre), not the
registration, and the frame is noted, kept for the guesses and its score refills the history.
Without that, one lasting drop flagged every later frame and the guesses came from ever older frames
(the talus of the 512² foot demo from frame 45 of 60 on, one H200). A score below the first frame's
floor is verified the same way (the demo's late-stance talus scores fall below it while the bone is
within 0.5 mm); a collapse always flags (:mod:`core.tracking.checks`). A bone outside a view's field
or a frame missing in a view is flagged with that reason, nothing is recorded, and tracking
continues. With ``max_uncertainty = (mm, degrees)`` a frame whose per-frame confidence (the length
of its σ vector in translation or rotation) exceeds either limit, or is not well posed, is flagged
``"uncertain"`` as well (recorded, not retried, still used for the guesses): registrations in the
noise's tail are then sent for review instead of passing silently. With the final stage
(``refine_likelihood``) a frame whose stage moved the pose (translation) more than
``stage_move_limit`` × the median move of the bone's last good frames, and more than
``stage_move_sigmas`` × its own translation σ, is flagged ``"uncertain"`` too, once the bone has
``stage_move_frames`` good frames with a move (the similarity and the weighted least-squares fit
disagree; :func:`core.tracking.frame_step.stage_move_check`, whose module docs give what it
caught); with ``stage_move_reject`` (the default) that frame keeps the similarity's pose — the
stage's move is rejected and the flag says so.

Three checks judge a frame by the bone's own track (:mod:`core.tracking.checks`): ``"unexpected
motion"`` — the pose farther from the constant-velocity prediction of the bone's last two good poses
than :data:`~core.tracking.checks.MOTION_LIMIT` × the median miss of that prediction over its last
``history`` good frames (at least :data:`~core.tracking.checks.MOTION_FLOOR`, grown with the frame
gaps; not confirmable: a frame's image of the bone at another pose is a true optimum that restarts
confirm), judged from the good poses, not from the start, so a wrong start that the retry corrected
is not flagged; ``"uncertain"`` (relative) — a confidence σ over
:data:`~core.tracking.checks.SIGMA_LIMIT` × the median of the bone's last good frames', or not well
posed where they were (recorded, not retried; like every frame flagged only ``"uncertain"``, it
still feeds the guesses and the score and motion histories, not the σ history: on the 512² foot
demo, one H200, with the metatarsal2's frames 35-37 flagged, two of them only ``"uncertain"``, and
left out, the velocity guesses extrapolated over the gap, 12-36° off in frames 38-45, and the bone
was lost from frame 46); and, while a bone has no good frame yet (its first frame flagged), a score
below ``min_score_ratio`` × the first flagged frame's is flagged ``"low score against the flagged
first frame"`` instead of passing unjudged.

Once every frame is tracked (a complete run), the trajectory post-pass of
:mod:`core.tracking.flags_post` flags ``"off the trajectory"`` the good frames whose pose stands off
the local fit through their neighbours by more than ``trajectory_limit`` (None: off) × the bone's
median residual — frames a few Cramér–Rao bound-widths off that converged and scored as usual, which
no check of a single frame tells apart (that module's docs give what it caught); those frames are
handed to ``record_result`` again with the flag. A range's fits run through ``neighbours``, good
poses outside it (the journal's), which are never flagged by it. Before it, the run's first frame is
registered once more as the frame step registers any later frame, from the guess the frames after it
give (:mod:`core.tracking.backward_check`): where the two registrations disagree by more than
``backward_limit`` (default 1.25, its own, not ``trajectory_limit``; None: off) × the bone's median
trajectory residual, the first frame is flagged
``"first frame off its backward registration"``, else noted (a run too short for that scale: noted, not
judged); a first frame is registered from a hand-placed keyframe and has no history that the checks of a
single frame could judge it by. The flag and note are journaled again through ``record_result``; the
window shows the flag once the run ends (it reloads the journal), ``progress`` is not called again.

The thresholds are :class:`TrackingOptions` fields, defaulting to the module constants named
above: ``collapse_ratio`` (:data:`~core.tracking.checks.COLLAPSE_RATIO`), ``motion_limit``,
``motion_floor`` (mm, degrees), ``sigma_limit`` (:data:`~core.tracking.options.CHECK_FIELDS`) and
the final stage's ``stage_move_limit``, ``stage_move_sigmas``, ``stage_move_frames``,
``stage_move_reject`` (:data:`~core.tracking.options.STAGE_MOVE_FIELDS`); ``talus track`` and
the window's *Tracking options* dialog set them.

``confidence_scale`` multiplies every frame's confidence σ: the curvature construction is a
scale, not a calibrated standard error, and a factor measured on a trial with ground truth
(:mod:`core.studies.tracking.hard_trial`) makes 2σ cover the error as often as it should.

Resume and cancel
-----------------
Every result with a pose is handed to ``record_result`` with its review state
(:meth:`FrameResult.journal_fields`; :func:`core.tracking.from_study.track_study` journals it
with :meth:`core.study.Trial.record_pose`). :func:`journal_inputs` turns the journal back into a
run's inputs: ``skip`` holds the frames done, as :class:`FrameResult` objects that keep their
flags, reasons, score and confidence — a flagged frame is not used for guesses and is **not
retried** (an uninterrupted run does not retry it either; clear the frame, or track it
without ``resume``, to register it again), a good frame's score refills the score history of the
checks — and the report of a resumed run holds them as the interrupted run left them. Keyframes
are the hand-set poses, which a tracking result does not replace in the journal, so a resumed
run starts from what the interrupted one started from. Each registration is seeded from its
frame number, never from what ran before, so a run killed at any moment and resumed, any number
of times, ends with the same poses, flags and report as an uninterrupted run (checked with
SIGKILLs by :mod:`core.studies.crash_resume`). A cancel drops the frame in flight whole: nothing
of it is recorded or reported, and the result says ``"cancelled"``.

False optima at the start
-------------------------
Every bone's first frame, and every frame that needed a retry, is checked by
``verify_restarts`` local restarts from its result displaced by ``verify_spread`` (mm, degrees)
(:func:`core.tracking.verify.verify_start`; Gauss–Newton restarts, half then full resolution, with
the newton search). When a restart scores higher, the first result was
a false optimum: a wider registration from the better restart follows and the best is kept
(noted as ``"start corrected by restarts"``; the frame is not flagged for it). When a restart
converges to a different pose with an equal score, the frame is flagged ``"ambiguous optimum"``.

Speed
-----
Tracking frames use the Gauss–Newton engine by default (``registration.search == "newton"``,
:data:`core.tracking.options.DEFAULT_SEARCH`; ``"local"`` runs the quadratic-model local search,
see :mod:`core.tracking.register`), and the per-frame confidence comes from its last
full-resolution fit, so a frame costs a few batched launches; only first frames, retries and
restarts run the global CMA-ES stage.
"""

from __future__ import annotations

import functools
import sys
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from contextlib import contextmanager

import numpy as np

from . import backward_check as backward
from .attempt import register_checked
from .bones import BoneModel
from .checks import SAME_OPTIMUM, pose_delta, same_optimum, step_pose  # noqa: F401 (SAME_OPTIMUM: the docs' name)
from .feed import FrameFeed
from .flags_post import apply_trajectory_flags, release_tables
from .frame_state import _BoneState, _Cancel, _Run, predict_pose
from .frame_step import track_frame
from .gc_pause import frozen
from .options import TrackingOptions
from .register_ahead import stage_idle
from .results import FrameResult, TrackingResult

__all__ = ["NEXT_FRAME_AHEAD", "FrameResult", "TrackingOptions", "TrackingResult", "device_lock",
           "journal_inputs", "predict_pose", "register_start", "track"]

#: One bone tracked with the final stage: the next frame (prepared by the feed's worker, where it is
#: ready) is put on the device (:func:`core.tracking.engine_upload.share`) while the device works on this
#: frame's final stage's first step (:func:`core.tracking.register.stage_idle`), where the host would
#: wait, instead of at the next frame's start (:data:`core.tracking.register.SHARE_FRAME`). This frame's
#: later registrations (a retry, the move's confirmation) upload its rows again; the same values. On with
#: :data:`~core.tracking.register.SHARE_FRAME` (timed there).
NEXT_FRAME_AHEAD = True

#: The objects alive when a run starts frozen out of the cyclic garbage collector while it runs
#: (:func:`core.tracking.gc_pause.frozen`): its full collections then walk the run's own objects, not the
#: process's few hundred thousand (150-222 ms a full collection on this 2-core x86_64 machine,
#: ``tracking_host_pauses_cpu.json``). The same poses and flags (tests). Off by default: on one NVIDIA H100's
#: host at f4f4b08 (``resources/benchmarks/tracking_bench_final_f4f4b08_h100.json``) runs with it on still had
#: full collections of 100-134 ms (one of frame_profile's four default runs, every bench process's first
#: three-bone run), and no run with it off had one (frame_profile, four alternated rounds, one bone: 0.4-0.7
#: ms of pauses a run off against 0.4-132.8 on): freezing seems to make a full collection come sooner (the
#: frozen objects no longer count towards its threshold) without making it cheap.
GC_FREEZE = False

#: The interpreter's thread switch interval (seconds, :func:`sys.setswitchinterval`) while a run tracks, put
#: back after; None (the default): left as it is (5 ms unless changed). The registering thread gives up the
#: interpreter at each wait for the device, and the feed's worker (the next frame's preparation,
#: :class:`core.tracking.feed.FrameFeed`) or the pyramid's threads may take it: where one of them then runs
#: Python code, the registering thread waits up to the interval for it back after the device is done. On
#: this 2-core x86_64 machine, shared, 400 sleeps of 0.2 ms overshot by 44 ms in all alone and 280 ms beside
#: a thread preparing 1024² frame pairs without pause, at 0.5 ms by 58 and 85 ms
#: (``resources/benchmarks/tracking_host_pauses_cpu.json``, :mod:`core.studies.tracking.host_pauses`); not
#: timed in a run.
#: The same poses either way (nothing computed depends on it).
SWITCH_INTERVAL = None

#: The backward check's frame (the run's first, registered again after the last: :mod:`core.tracking.
#: backward_check`) read and prepared while the last frame registers, as every frame is while the one
#: before it registers (:class:`core.tracking.feed.FrameFeed`), and with one bone put on the device during
#: the last frame's final stage (:data:`NEXT_FRAME_AHEAD`), instead of after the loop: on one NVIDIA H100
#: the check's frame read and its upload took 1.07 + 1.05 ms after the last frame
#: (``profile_one_bone_ad38ce9_h100.json``). The same frame, the same poses and flags (tests); wasted where
#: the check then finds nothing to register (a cancelled run, a resumed one whose first frame is given).
BACKWARD_AHEAD = True


def journal_inputs(states: Mapping, frames: Sequence[int], *, resume: bool = False) -> tuple[dict, dict]:
    """``(keyframes, skip)`` for :func:`track` from each bone's journal (a mapping bone name ->
    :class:`core.study.JournalState`) over the tracking range ``frames``.

    Keyframes are the poses a run over ``frames`` starts from: in the range the hand-set poses
    (:attr:`~core.study.JournalState.keyframes`, which tracking results do not replace), outside
    it every recorded pose. With ``resume`` the frames of the range already done are skipped:
    tracking results come back as :class:`FrameResult` with their review state (flagged frames
    stay flagged and are not used for guesses, their scores refill the score history, and the
    report holds them), hand fixes and version-1 poses as poses. Both runs of a resumed range —
    the interrupted one and the one that completes it — thus see the same inputs, and the
    resumed run gives the report the uninterrupted run would have given (frames flagged for
    review are not retried on resume: an uninterrupted run does not retry them either)."""
    rng = {int(f) for f in frames}
    keyframes, skip = {}, {}
    for b, st in states.items():
        kf = {f: r.pose for f, r in st.keyframes.items() if f in rng}
        kf.update({f: r.pose for f, r in st.records.items() if f not in rng and r.pose is not None})
        keyframes[b] = dict(sorted(kf.items()))
        done = {}
        if resume:
            for f, r in st.done.items():
                if f in rng:
                    done[f] = FrameResult.from_journal(b, r) if r.kind == "tracked" else r.pose
        skip[b] = done
    return keyframes, skip


def track(renderer, bones: Sequence[BoneModel], frames: Callable[[int], Sequence],
          frame_order: Sequence[int], *,
          keyframes: Mapping[str, Mapping[int, np.ndarray]], options: TrackingOptions | None = None,
          record: Callable[[str, int, np.ndarray, float], None] | None = None,
          record_result: Callable[[FrameResult], None] | None = None,
          skip: Mapping[str, Mapping[int, np.ndarray | FrameResult]] | None = None,
          progress: Callable[[int, int, FrameResult], None] | None = None,
          cancel: Callable[[], bool] | None = None,
          neighbours: Mapping[str, Mapping[int, np.ndarray]] | None = None) -> TrackingResult:
    """Track ``bones`` (volume ``i`` of ``renderer`` is ``bones[i]``) over ``frame_order``.

    Parameters
    ----------
    frames : callable(frame) -> sequence
        Per view the flatfield-normalised image in [0, 1], or None where that view has no frame
        (or a :class:`core.tracking.feed.MissingView` carrying why).
        Called once per frame, in tracking order, one frame ahead of the registration (frame
        ``k + 1`` is read before frame ``k`` is registered, :mod:`core.tracking.feed`); a
        callable that refills one buffer is noticed then, and its frames are read at their turn.
        A callable with a ``reason(frame, view)`` method says why a view has none (e.g. its file
        and the reader's error): the frame's flag then gives it ("frame cannot be read: view 2:
        <reason>", views counted from 1) instead of "frame missing in view 2".
    frame_order : sequence of int
        Frames in tracking order (``range(a, b)`` forward, ``range(b - 1, a - 1, -1)`` backward).
    keyframes : mapping bone name -> {frame: pose}
        Starting poses (at least one per bone) and spline knots.
    record : callable(bone, frame, pose, score), optional
        Called as soon as each (bone, frame) with a pose is registered.
    record_result : callable(FrameResult), optional
        Called likewise with the whole result (pose, score and review state), e.g. to journal
        it with :meth:`core.study.Trial.record_pose` (``tracking=fr.journal_fields()``).
        Results without a pose (outside a view, frame missing) are not recorded; they are
        registered again on resume, with the same outcome.
    skip : mapping bone name -> {frame: pose or FrameResult}, optional
        Frames already done (resume, see :func:`journal_inputs`): not registered again. A
        :class:`FrameResult` is taken back as it was (into the result and its report, through
        ``progress``; a flagged one is not used for guesses, a good one's score refills the
        score history); a pose is a good pose that feeds the guesses. In joint mode a frame
        in which some bone still needs registering is registered again for every bone whose
        entry is a FrameResult (the bones' registrations depend on each other there).
    progress : callable(done, total, FrameResult), optional
    cancel : callable() -> bool, optional
        Polled between registrations and once per optimiser generation. Once it has returned
        True the frame in flight is dropped whole (nothing of it is recorded or reported) and
        the result says ``"cancelled"``; a cancel that comes after the last frame is recorded
        leaves the run ``"complete"``.
    neighbours : mapping bone name -> {frame: pose}, optional
        Good poses of frames outside ``frame_order`` (the journal's,
        :func:`core.tracking.flags_post.journal_neighbours`): the trajectory post-pass fits through
        them, and through ``skip``'s poses, but flags only this run's frames.

    Frames are registered from their inputs only (the seeds depend on the frame, not on what
    ran before), so a run resumed from its journal gives the results of an uninterrupted run.
    A second tracking on the same device in another thread waits for this one (:func:`device_lock`).
    """
    o = options or TrackingOptions()
    order = [int(f) for f in frame_order]
    if len(bones) != len(renderer.volumes):
        raise ValueError(f"bones: expected {len(renderer.volumes)} bone models, one per renderer volume")
    names = tuple(b.name for b in bones)
    for b in names:
        if not (keyframes.get(b) or (skip or {}).get(b)):
            raise ValueError(f"keyframes: bone {b!r} has no keyframe to start from")
    skip = {b: dict((skip or {}).get(b, {})) for b in names}
    state = {b: _BoneState() for b in names}
    joint = o.mode == "joint" and len(names) > 1
    contacts = None
    if joint and o.contact:
        from .contact import ContactModel

        contacts = [ContactModel.from_bone(b) for b in bones]
    run = _Run(renderer, bones, names, keyframes, o, _Cancel(cancel), contacts)
    with device_lock(getattr(renderer, "device", None)), frozen(GC_FREEZE), _switch_interval(SWITCH_INTERVAL):
        return _track_frames(run, bones, names, order, skip, state, o, frames, neighbours, record,
                             record_result, progress)


_DEVICE_LOCKS: dict[str, threading.RLock] = {}
_DEVICE_LOCKS_MADE = threading.Lock()


def device_lock(device) -> threading.RLock:
    """The device's one registering thread: :func:`track` holds this lock for its whole run, so a second
    tracking on the same device in another thread waits for the first to finish. Warp's current stream is
    one per device for every thread, and a graph being captured on it would take another thread's launches
    (or refuse their synchronisation); two runs at once also share Warp's CPU tile kernels' shared memory.
    Re-entrant (a tracking inside a tracking's callback on the same thread does not wait); keyed by the
    device's name (``str(device)``; ``None``: one lock for renderers without a device)."""
    key = str(device)
    lock = _DEVICE_LOCKS.get(key)
    if lock is None:
        with _DEVICE_LOCKS_MADE:
            lock = _DEVICE_LOCKS.setdefault(key, threading.RLock())
    return lock


def _track_frames(run, bones, names, order, skip, state, o, frames, neighbours, record, record_result,
                  progress) -> TrackingResult:
    """:func:`track`'s frames, checks and post-passes (its arguments checked)."""
    joint = o.mode == "joint" and len(names) > 1
    results: dict = {}
    total, done = len(order) * len(names), 0
    t0 = time.perf_counter()
    status = "complete"
    changed: set = set()  # (bone, frame) of the results the post-passes changed

    def finish(fr: FrameResult) -> None:
        nonlocal done
        results[(fr.bone, fr.frame)] = fr
        done += 1
        if progress is not None:
            progress(done, total, fr)

    def todo_of(f: int) -> tuple[dict, list]:
        """Frame ``f``'s results taken back as they were, and the bones to register."""
        restored = {i: skip[b][f] for i, b in enumerate(names)
                    if f in skip[b] and isinstance(skip[b][f], FrameResult)}
        todo = [i for i, b in enumerate(names) if f not in skip[b]]
        if joint and todo:
            todo = sorted(todo + list(restored))
            restored = {}
        return restored, todo

    feed = FrameFeed(frames, o.valid_range, o.erode_px)
    try:
        for k, f in enumerate(order):
            if run.cancel():
                status = "cancelled"
                break
            restored, todo = todo_of(f)
            for i, b in enumerate(names):
                if f in skip[b] and i not in restored and i not in todo:  # a pose: a good frame, as given
                    state[b].add_good(f, skip[b][f], None)
                    done += 1
            new = {}
            if todo:
                imgs, frame = feed.get(f)
                nxt = k + 1 < len(order) and bool(todo_of(order[k + 1])[1])
                if nxt:  # prepared while this one registers
                    feed.prefetch(order[k + 1])
                elif BACKWARD_AHEAD and k + 1 == len(order) and backward.applies(order, o):
                    feed.prefetch(order[0])  # the backward check's frame, read again (BACKWARD_AHEAD)
                    nxt = True
                # one bone: the next frame put on the device while this one's final stage runs
                ahead = None
                if NEXT_FRAME_AHEAD and nxt and len(names) == 1 and o.registration.final is not None:
                    ahead = functools.partial(_stage_work, feed, run.renderer.device)
                with stage_idle(ahead):
                    new = track_frame(run, f, imgs, frame, todo, state, skip)
            if new is None:
                status = "cancelled"
                break
            for i, b in enumerate(names):
                fr = restored.get(i) or new.get(i)
                if fr is None:
                    continue
                if i in new and fr.pose is not None:
                    if record is not None:
                        record(b, f, fr.pose, fr.score)
                    if record_result is not None:
                        record_result(fr)
                state[b].add(f, fr)
                finish(fr)
        if status == "complete" and o.backward_limit is not None:  # the first frame again, from later frames
            changed = {(fr.bone, fr.frame)
                       for fr in backward.backward_check(run, feed, order, results, skip, track_frame)}
    finally:
        feed.close()
    out = TrackingResult(names, tuple(order), results, status, time.perf_counter() - t0)
    try:
        if status == "complete" and o.trajectory_limit is not None:  # review flags from the whole track
            centers = {b.name: b.centroid for b in bones}
            near = {b: {**(neighbours or {}).get(b, {}),
                        **{f: p for f, p in skip[b].items() if not isinstance(p, FrameResult)}}
                    for b in names}
            out, again = apply_trajectory_flags(out, centers, limit=o.trajectory_limit, neighbours=near)
            changed |= {(fr.bone, fr.frame) for fr in again}
    finally:
        release_tables()  # (the backward check's tables the post-pass did not take: flags_post.SHARE_TABLE)
    for key in sorted(changed, key=lambda k: (k[1], names.index(k[0]))):  # journaled again with the flag or
        fr = out.results[key]  # note (the review panel reads the journal)
        if record_result is not None and fr.pose is not None:
            record_result(fr)
    return out


_SWITCHED = {"runs": 0, "kept": None}  # runs inside _switch_interval and the interval before the first
_SWITCH_LOCK = threading.Lock()


@contextmanager
def _switch_interval(seconds):
    """:data:`SWITCH_INTERVAL` within the block (None: nothing); runs in several threads share it: the
    first to enter keeps the interval it found, the last to leave puts it back."""
    if seconds is None:
        yield
        return
    with _SWITCH_LOCK:
        if _SWITCHED["runs"] == 0:
            _SWITCHED["kept"] = sys.getswitchinterval()
        _SWITCHED["runs"] += 1
        sys.setswitchinterval(float(seconds))
    try:
        yield
    finally:
        with _SWITCH_LOCK:
            _SWITCHED["runs"] -= 1
            if _SWITCHED["runs"] == 0:
                sys.setswitchinterval(_SWITCHED["kept"])


def _stage_work(feed: FrameFeed, device, res) -> None:
    """What one bone's frame does while the device works on its final stage: the next frame put on the
    device (:data:`NEXT_FRAME_AHEAD`)."""
    feed.upload_ahead(device)


def register_start(renderer, frame, bone: BoneModel, index: int, start, *,
                   options: TrackingOptions | None = None, others=None, cancel=None, seed: int = 0):
    """Register ``bone`` (volume ``index`` of ``renderer``) in one prepared ``frame`` from a
    hand-placed ``start`` exactly as :func:`track` does a bone's first frame: the widened
    first-frame options, the failure checks with a wider retry and the restart check of
    :func:`core.tracking.verify.verify_start`. Returns a :class:`FrameResult` (frame -1)."""
    o = options or TrackingOptions()
    a = register_checked(renderer, frame, bone, index, start, start, o.first_options, o, [], others, cancel,
                         [], verify=True, seed=seed)
    if a.result is None:
        return FrameResult(bone.name, -1, None, np.nan, a.evaluations, a.time_s, False, tuple(a.flags),
                           a.retried, None, a.timing)
    return FrameResult(bone.name, -1, a.result.pose, a.result.score, a.evaluations, a.time_s, not a.flags,
                       tuple(a.flags), a.retried, a.confidence, a.timing, a.notes)
