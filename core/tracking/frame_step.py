"""One frame of :func:`core.tracking.trial.track`: every bone's registrations, rounds and checks.

:func:`track_frame` registers the bones of one frame — one bone at a time, or jointly in
``joint_rounds`` rounds (1 by default since 8dbdcc2; each bone with its neighbours subtracted at their
latest estimates: with one round, in a first frame, only the bones registered before it) —
each registration with the checks of :func:`core.tracking.attempt.register_checked`, and returns
a :class:`~core.tracking.results.FrameResult` per bone. In joint rounds before the last, a
registration's confidence (and its ``"uncertain"`` checks) is computed only where its attempt is
the one kept (:func:`~core.tracking.attempt.settle`; the next round's replaces it otherwise).

The registrations' final stage (``final`` of the registration options, ``TrackingOptions.
refine_likelihood``; :mod:`core.tracking.final_stage`) runs in the last round only: a round before
it only gives the next round its start and the neighbours' poses to subtract, which the similarity's
optimum does as well, so each bone is refined once per frame (with its neighbours at the poses of
the round before), in joint as in sequential mode. With one joint round (the default since 8dbdcc2)
there is no round before: the stage subtracts the neighbours at their predictions (in lockstep every
neighbour; one by one, those not yet registered in the frame), as round 0's search does; every
joint figure with the stage was measured with two rounds. A bone that a later round loses (outside a view)
keeps the earlier round's pose, without the stage. Without a final stage nothing changes. On one
NVIDIA H200 (1024², 100 frames, three bones jointly, the same call,
``resources/benchmarks/tracking_final_rounds_h200.json``) the stage after the last round took
93.1 ms per frame after the first where after every round it took 161.1 ms (the tracker without it
14.7 ms; the stage 24.8 ms per bone-frame, 14.0 ms of it host set-up), with the same errors (tibia,
talus, calcaneus 4.34/1.69, 1.36/1.28, 1.90/1.41 × the Cramér–Rao bound in mm/degrees, against
4.34/1.69, 1.37/1.30, 1.89/1.40).

With the final stage, a frame whose stage moved the pose far more than the bone's other frames' stages
did is flagged ``"uncertain"`` and the move rejected, unless the stage run again from the far side
of its pose confirms it (:data:`STAGE_MOVE_CONFIRM`): :mod:`core.tracking.stage_move` (the check, its
thresholds and what it caught).

In sequential tracking of several bones the final stage subtracts the neighbours too, as joint
tracking's does (:data:`SEQUENTIAL_NEIGHBOURS`): the bones registered earlier in the frame at
their registered poses, the others at their guesses (the constant-velocity prediction, or the given
pose of a bone not tracked in the frame); the similarity's search is not changed (no neighbours, as
before; :func:`core.tracking.final_stage.stage_neighbours`). On the harder trial
(:mod:`core.studies.tracking.hard_trial`, 1024², 20 frames, GC components, one NVIDIA H200) the
talus went from 0.159° to 0.132° RMS sequentially (jointly 0.134°), the tibia and calcaneus
stayed within 0.001° of their joint values (0.082°, 0.081°).

Sequential tracking searches each bone against the whole image, its neighbours' projections in it;
with ``TrackingOptions.sequential_subtract`` the search subtracts them as the stage does (the bones
registered earlier in the frame at their registered poses, the others at their guesses; one pass,
no rounds). On the acceptance trial (one NVIDIA H100, 1024², 100 frames, Gauss–Newton search,
``resources/benchmarks/sequential_drift_h100.json``) the whole image biased the tibia about its long
axis (over frames 50-72 the estimate scored higher than the truth in 21 of 23 frames, and a search
restarted from the truth went back towards it) and the talus: 9 / 7 / 0 silent frames over 4× the
Cramér–Rao bound (tibia, talus, calcaneus), × the bound 1.79 / 2.46, 2.23 / 2.17, 1.59 / 1.43 (mm /
°); subtracted, 0 / 0 / 0 and 1.71 / 1.79, 1.78 / 1.58, 1.29 / 1.50 (joint tracking 1 / 0 / 0;
:mod:`core.studies.tracking.sequential_drift`). On two more syntheses of the trial it tracked as
joint tracking does (silent 8 / 0 / 0 and 2 / 0 / 0, jointly 7 / 0 / 0 and 2 / 0 / 0, alone 9 / 0 / 0
and 4 / 1 / 0; ``sequential_drift_seeds_h100.json``). None by default ("auto"):
:func:`core.tracking.from_study.track_study` turns it on where it finds the frames
flatfield-corrected and off for frames divided by the full scale, whose DRR intensities are not
matched to the images and where subtraction does harm; :func:`core.tracking.trial.track` alone
cannot tell and keeps it off. A bone whose result of the frame is taken back from the journal
(resume) is subtracted at that pose, as the run that registered it did. A bone with a keyframe in
the frame (a hand-set pose, the user's pose of it there) is subtracted at it until it is registered
in the frame, in the search and the final stage: without, in the first frame of a run started from
keyframes the first bone had nothing subtracted (no other bone had a tracked pose yet), and a
keyframe later in the range gave way to the constant-velocity guess. A keyframe off the truth is
subtracted where the bone is not, and leaves its negative in the image (from 5 mm / 5° off, the talus
of the ideal 128² scene registered first 0.3-2.6° off, unflagged): so a first frame gets a second pass,
every bone with the others at their first pass's poses (:data:`SEQUENTIAL_SECOND_PASS`). Joint tracking
is unchanged (its first round in a first frame subtracts only the bones registered before it): doing as
sequential tracking does (:data:`JOINT_KEYFRAMES`) helped from keyframes near the truth and harmed from
keyframes 3-5 mm / 3-5° off (off by default); a second round in the first frame
(:data:`FIRST_FRAME_SECOND_ROUND`) helped from 5 mm / 5° and is on by default (their docs give the figures).

Joint rounds in lockstep (:func:`core.tracking.joint.register_together`) need the previous
round's poses, which its checks may still change (a flagged registration is retried wider). The
checks seldom change a pose, and they are host work, while the next round is device work: so the
next round is started from the poses the checks would leave when they pass (the same jobs the
tracker builds after them: the same starts, neighbours and search regions), and the checks run
on the host while the device works on its steps
(``idle`` of :func:`~core.tracking.joint.register_together`). A check that would need the device
(a retry, the restart check, a confidence from a cost of its own) is left for after the round and
run as before; the round started ahead is used only where the jobs built after every check are
those it was started with (the same bytes), otherwise it is dropped and run again from the
checked poses. The results are those of checking first.

Off by default (:data:`AHEAD`; with one round, the default, there is no next round to start): on
one NVIDIA H100 (1024², 100 frames, three bones jointly in two rounds, the default then,
``resources/benchmarks/tracking_newton_h100_margin.json``) it gave 13.89 ms per frame after the
first where checking first gave 13.87 ms. The lockstep loop is host-bound — the device waits for
each lane's host arithmetic more than the host waits for the device — so the checks run in the
loop move host time rather than hide it, and a dropped round (a check that moves a pose) costs a
whole round. It pays once the host's share of a step falls below the device's.
"""

from __future__ import annotations

import time
from contextlib import nullcontext
from dataclasses import replace as _replace

import numpy as np

from .attempt import Attempt, limits_ahead, register_checked, settle
from .checks import same_optimum
from .cost import OutsideViewError
from .frame_records import MISSING_FLAG, UNREADABLE_FLAG, missing_flags
from .frame_records import Work as _Work
from .frame_records import frame_result as _frame_result
from .frame_state import _BoneState, _Run, motion_prediction, predict_pose
from .joint import JointJob, lockstep_applies, register_together
from .keep_apart import keep_apart
from .options import STAGE_MOVE_FRAMES, STAGE_MOVE_LIMIT, STAGE_MOVE_SIGMAS
from .register import RegistrationOptions
from .results import FrameResult
from .second_pass import stage_pass
from .stage_move import confirmed, stage_move_check

__all__ = ["AHEAD", "CONFIRM_FLOOR_MM", "FINAL_EVERY_ROUND", "FIRST_FRAME_AGAIN_MOVED", "FIRST_FRAME_AS_PASS",
           "FIRST_FRAME_CHECK_FROM_ROUND0", "FIRST_FRAME_MOVE_FLOOR", "FIRST_FRAME_SECOND_ROUND",
           "JOINT_KEYFRAMES", "MISSING_FLAG", "RESTART_FROM_PREDICTION", "SECOND_PASS_STAGE_ONLY",
           "SEQUENTIAL_NEIGHBOURS", "SEQUENTIAL_SECOND_PASS", "STAGE_MOVE_CONFIRM",
           "STAGE_MOVE_FRAMES", "STAGE_MOVE_LIMIT", "STAGE_MOVE_SIGMAS", "UNREADABLE_FLAG", "missing_flags",
           "stage_move_check", "track_frame"]

#: Start joint tracking's next lockstep round before this round's checks (module docs; measured no
#: faster on one H100 while the loop is host-bound).
AHEAD = False
#: Run the registrations' final stage after every joint round, not only the last (as before; kept
#: for comparison by :mod:`core.studies.tracking.ml_cost`).
FINAL_EVERY_ROUND = False
#: Joint tracking's rounds after the first start each bone (one with a history: not a first frame)
#: from its prediction, as round 0 does, its neighbours subtracted at their previous round's poses;
#: off (the default): from its previous round's pose, a second search that keeps less of the
#: prediction along the cost's flat directions than sequential tracking's one search does
#: (:mod:`core.studies.tracking.joint_gap`). The user's option is ``TrackingOptions.joint_restart``
#: (``talus track --joint-restart``); this switch, kept for the studies, turns it on for every run
#: of two rounds or more: a restart needs ``joint_rounds`` ≥ 2, and with one round (the default
#: since 8dbdcc2) it does nothing (:mod:`~core.studies.tracking.joint_gap` pins two rounds for it).
RESTART_FROM_PREDICTION = False
#: Sequential tracking's final stage subtracts the neighbours (the bones registered in the frame, the
#: others at their guesses; off: none, as before; kept for comparison by studies).
SEQUENTIAL_NEIGHBOURS = True
#: A stage move the move check flags is first confirmed (:func:`core.tracking.final_stage.confirm_move`:
#: the stage run again from the far side of its pose lands on the same pose): confirmed, the frame keeps
#: the stage's pose, unflagged, with a note; off, or not confirmed, it is flagged (and rejected) as before.
#: (:mod:`core.studies.tracking.stage_residue`: on held-out seed 4 the check rejected moves that
#: took the talus's similarity optimum back from 0.47° off.) What it tests is that the stage's pose
#: does not depend on where the stage began, not that it is right: a move to a biased optimum of the
#: stage's cost that both starts reach (as on the trial where the rejection was measured: the plain
#: stage, no robust weights, moved the tibia 0.08-0.24 mm in frames 72-89 and its error there was
#: the move; ``tracking_final_reject_h200.json``) can be confirmed and kept: the confirmation has
#: not been run on that case. Its cost falls on flagged frames only (the held-out seed 3 and 4 runs
#: with the default stage had at most 3 of a run's 300 bone-frames flagged other than by the
#: trajectory check): there the second run to tol took 9-15 steps against the first's 3-4 (512²,
#: ``tracking_stage_residue_cpu.json``'s confirm part).
STAGE_MOVE_CONFIRM = True
#: The confirmation's translation floor (mm): a second run within it of the stage's pose, and within half
#: the move, confirms it where the rotation passes ``confirm_move``'s test (which has a 0.05° floor for
#: the rotation, none for the translation: moves of little translation were rejected; :func:`_confirmed`).
CONFIRM_FLOOR_MM = 0.02
#: Joint tracking subtracts a bone with a keyframe in the frame (the user's pose of it there) at it until it
#: is registered in the frame, as sequential tracking does; off (the default): as before, a first frame's
#: round 0 registers the bones one after another and the first has nothing subtracted. Measured on the
#: ideal 128² talus-calcaneus scene (CPU, one round; ``test_joint_first_frame_keyframes.py``):
#: the talus's first-frame error went from 0.234 mm / 0.513° to 0.0003 mm / 0.003° from keyframes at the
#: truth, and from 0.24-0.26 mm / 0.33-0.40° to 0.08-0.09 mm / 0.21-0.26° from keyframes 1 mm / 1° off, but
#: from keyframes 5 mm / 5° off (the acceptance study's) its rotation was worse in 4 of 5 draws, up to
#: 2.76° against 0.26°, unflagged (3 mm / 3°: 2 of 4 worse, to 2.1°), sequential tracking's poses: a
#: neighbour subtracted where it is not leaves its image's negative where it is.
JOINT_KEYFRAMES = False
#: Joint tracking's first frame (a bone in it without a tracked pose) gets a second round whatever
#: ``joint_rounds`` holds: every bone again with its neighbours at their round-0 poses, so the bone
#: registered first is registered once more with the others subtracted. On by default: with one round
#: (the default since 8dbdcc2) the first frame is as two rounds made it before, at one extra round on that
#: frame only. Same scene, keyframes 5 mm / 5° off, one round: the talus 0.19-0.28 mm / 0.25-0.64° →
#: 0.0004-0.0013 mm / 0.002-0.004° (4 draws; the calcaneus, registered after the talus, unchanged); later
#: frames unchanged. On held-out seed 4 (one NVIDIA H100, 1024², no stage) the tibia's frame 0 was 1.21°
#: off with two rounds and 1.57° with one (sequentially 0.25°); the switch not yet run there.
FIRST_FRAME_SECOND_ROUND = True
#: Sequential tracking that subtracts the neighbours (``sequential_subtract``, or the final stage's
#: :data:`SEQUENTIAL_NEIGHBOURS`) gives a first frame (a bone in it without a tracked pose) a second pass:
#: the first pass again (from the keyframes, the first frame's options) with the others at their first
#: pass's poses, each checked from its first pass's pose (the first pass subtracts a bone not yet registered
#: at its keyframe: off the truth, its negative where the bone is not). Ideal 128² scenes (CPU, this 2-core
#: x86_64 machine; ``sequential_subtract``, no restarts), keyframes 5 mm / 5° off: talus-calcaneus (6 draws)
#: the talus 0.06-0.38 mm / 0.32-2.58° → 0.0004-0.0029 mm / 0.003-0.011°, the calcaneus 0.002-0.030 mm /
#: 0.017-0.069° → ≤ 0.0024 mm / 0.006°, the frame's evaluations ×1.84-1.98; tibia-talus-calcaneus (4
#: draws) the tibia up to 1.07° → ≤ 0.075°, the talus 0.25-0.62° → ≤ 0.009°
#: (``resources/benchmarks/first_frame_keyframes_sequential*_cpu.json``). From the first pass's poses
#: instead (×1.3-1.5 evaluations) the tibia stayed 0.27-0.45° off (2 draws): its search stopped short.
#: The final stage alone subtracting (no ``sequential_subtract``): the talus 0.64-0.94° → 0.040-0.045° (3
#: draws). Later frames unchanged. The second pass runs the first pass's restart check too (figures before);
#: with the stage but not ``sequential_subtract``, only the stage (:data:`SECOND_PASS_STAGE_ONLY`).
SEQUENTIAL_SECOND_PASS = True
#: Joint tracking's first-frame second round (:data:`FIRST_FRAME_SECOND_ROUND`) is checked from the bone's
#: round-0 pose where round 0 left it unflagged (the lockstep round only: with :data:`FIRST_FRAME_AS_PASS`
#: it always is; the round after it, :data:`FIRST_FRAME_AGAIN_MOVED`, is checked from the lockstep round's
#: poses); off (the default): from its keyframe, as round 0, but without
#: the first frame's wider jump limit, so a pose come back from a keyframe 5 mm off is taken for a jump and
#: retried from the keyframe, widened. (Sequential tracking's second pass is always checked from its first
#: pass's pose, and starts from the keyframe with the first frame's options: :data:`SEQUENTIAL_SECOND_PASS`.)
#: Ideal 128² scenes (CPU, this 2-core x86_64 machine), keyframes 5 mm / 5° off, one round: on, the
#: talus-calcaneus frame's evaluations 3195-3664 → 1677-1930 (6 draws), the talus 0.0005-0.0019 mm /
#: 0.002-0.007° → 0.003-0.006 mm / 0.004-0.008°; but with the tibia (three bones; the lockstep round from
#: round 0's poses, the registration's options) the tibia 0.023-0.032° → 0.39-0.50° (4 draws): the retry,
#: wide from the keyframe, was what registered it (``resources/benchmarks/first_frame_keyframes_joint*``).
FIRST_FRAME_CHECK_FROM_ROUND0 = False
#: Joint tracking's first-frame second round (:data:`FIRST_FRAME_SECOND_ROUND`) as sequential tracking's
#: second pass (:data:`SEQUENTIAL_SECOND_PASS`): the bones without a tracked pose one at a time, not in
#: lockstep (each with the bones before it at this round's poses, the others at round 0's), each from its
#: keyframe with the first frame's options, checked from its round-0 pose where round 0 left it unflagged,
#: with round 0's restart check (a flag of round 0's checks stands unless the same checks clear it). In
#: lockstep every neighbour was subtracted at its round-0 pose and the round had no restart check. Ideal 128²
#: tibia-talus-calcaneus scene (CPU, this 2-core x86_64 machine), keyframes 5 mm / 5° off, 6 draws: the talus
#: 0.024-0.027 mm / 0.113-0.123° (the tibia subtracted at its round-0 pose, 0.86° off on draw 0; at the truth:
#: 0.002°) → 0.0005-0.0018 mm / 0.0041-0.0057° (sequentially 0.0005-0.0025 mm / 0.0017-0.0086°), the calcaneus
#: 0.015-0.019° → 0.0004-0.0076° (sequentially 0.0017-0.0062°), the tibia, registered first either way, the
#: same 0.005-0.032° (sequentially 0.005-0.075°); the frame's evaluations 5049-5457 → 5010-5442 (with 4
#: restarts, 2 draws: 6609-7019 → 6583-6753). Talus-calcaneus (6 draws): the talus the same, the calcaneus
#: 0.004-0.012° → 0.003-0.007°, 3195-3664 → 3204-3433 evaluations
#: (``resources/benchmarks/first_frame_keyframes_joint*_pass*_cpu.json``). Off (the default since the 1024²
#: cost below): the lockstep round (:data:`FIRST_FRAME_AGAIN_MOVED`). One bone at a time, the joint first
#: frame of ``talus bench track`` (three bones with the stage, 1024², one NVIDIA H100) took 348 ms against
#: 171 ms in lockstep, and three bones fell from 50.2 to 43.1 frames/s; at 1024² seeds 0, 3, 4's joint first
#: frames were already as good as sequential tracking's (the talus 0.23/0.13/0.21° against 0.24/0.14/0.20°).
FIRST_FRAME_AS_PASS = False
#: Joint tracking's first-frame second round (:data:`FIRST_FRAME_SECOND_ROUND`; not with
#: :data:`FIRST_FRAME_AS_PASS`) in lockstep as before (from round 0's poses, the neighbours at theirs, checked
#: from the keyframes), with round 0's restart check where round 0 left the bone flagged (its flag stands
#: unless the same checks clear it; before, that round dropped it); then, side by side again, the bones left
#: unflagged whose neighbours moved in that round by more than :data:`FIRST_FRAME_MOVE_FLOOR` once more, from
#: their poses, the neighbours at theirs, checked from them (the final stage runs in both rounds). Where no
#: neighbour moved, the frame costs one lockstep round, as before. Ideal 128² scenes (CPU, this 2-core x86_64
#: machine, shared; one joint round, no restarts), keyframes 5 mm / 5° off, 6 draws: tibia-talus-calcaneus,
#: every bone once more, the talus 0.024-0.027 mm / 0.113-0.123° (the tibia subtracted at its round-0 pose,
#: 0.86° off on draw 0) → 0.0012-0.0022 mm / 0.0032-0.0050° (one at a time, :data:`FIRST_FRAME_AS_PASS`:
#: 0.0041-0.0057°), the calcaneus 0.015-0.019° → 0.0018-0.0039°, the tibia 0.005-0.032° → 0.005-0.009°, the
#: frame's evaluations 5049-5457 → 5088-5496 (13 a bone); talus-calcaneus, the calcaneus once more,
#: 0.004-0.012° → 0.002-0.003°, the talus unchanged, 3195-3664 → 3208-3677
#: (``resources/benchmarks/first_frame_again_moved_cpu.json``). Off: the lockstep round alone, as before
#: bae210d.
FIRST_FRAME_AGAIN_MOVED = True
#: :data:`FIRST_FRAME_AGAIN_MOVED`'s floor (mm, degrees): a neighbour's move in the round (its pose subtracted
#: against its new one) beyond either sends the bone round once more (the confirmation floor,
#: :data:`CONFIRM_FLOOR_MM`, and :func:`core.tracking.final_stage.confirm_move`'s 0.05°).
FIRST_FRAME_MOVE_FLOOR = (0.02, 0.05)
#: Sequential tracking's first-frame second pass (:data:`SEQUENTIAL_SECOND_PASS`) with the final stage but
#: without ``sequential_subtract`` runs the stage alone from the first pass's pose, the first pass's restart
#: check's verdict kept (:mod:`core.tracking.second_pass`): its search would repeat the first pass's (no
#: neighbours subtracted in either). Off: the whole first pass again, the stage at its end (as before).
#: Ideal 128² scenes, keyframes 5 mm / 5° off (CPU, this 2-core x86_64 machine): every pose and flag the
#: same to the bit, a bone's frame evaluations ×0.48-0.51 (``second_pass_stage_cpu.json``; the module's docs).
SECOND_PASS_STAGE_ONLY = True


def track_frame(run: _Run, f: int, imgs: list, frame, todo: list[int], state: dict[str, _BoneState],
                skip: dict) -> dict[int, FrameResult] | None:
    """Register bones ``todo`` in frame ``f`` (``frame``: the prepared ``imgs``); their results,
    or None when cancelled. A view without its image (None, or a
    :class:`~core.tracking.feed.MissingView` with its source's reason) flags every bone of the
    frame (:func:`missing_flags`)."""
    o, names, bones = run.options, run.names, run.bones
    flags = missing_flags(imgs)
    if flags:
        return {i: FrameResult(names[i], f, None, np.nan, 0, 0.0, False, flags) for i in todo}
    hist = {b: state[b].history for b in names}
    # each bone's constant-velocity prediction: the velocity guess and what the motion check judges
    # every registration of the frame against (computed once here)
    predicted = {i: motion_prediction(hist[names[i]], f, bones[i].centroid) for i in todo}
    guesses = {i: predict_pose(hist[names[i]], f, bones[i].centroid, guess=o.guess,
                               keyframes=run.keyframes.get(names[i]), prediction=predicted[i]) for i in todo}
    joint = o.mode == "joint" and len(names) > 1
    # sequential tracking with the final stage: the stage subtracts the neighbours as joint tracking
    # does (the bones registered in this frame, the others at their guesses; module docs)
    seq_stage = (not joint and len(names) > 1 and o.registration.final is not None and SEQUENTIAL_NEIGHBOURS)
    # sequential_subtract: the search subtracts them as well (module docs)
    seq_search = not joint and len(names) > 1 and o.sequential_subtract
    # the first frame's second pass without sequential_subtract: the stage alone (SECOND_PASS_STAGE_ONLY)
    stage_only = seq_stage and not seq_search and SECOND_PASS_STAGE_ONLY
    current = dict(guesses)  # each bone's latest estimate in this frame (joint: what is subtracted)
    if joint or seq_stage or seq_search:
        for i, b in enumerate(names):
            done = getattr(skip[b].get(f), "pose", None)  # a result of this frame taken back (resume)
            if i not in current and done is not None and np.all(np.isfinite(done)):
                current[i] = np.asarray(done, dtype=float)  # (track adds it to the history after)
            elif i not in current:  # skipped: given as a pose (see track)
                current[i] = hist[b][-1][1] if hist[b] else predict_pose(
                    [], f, bones[i].centroid, keyframes=run.keyframes.get(b) or {
                        k: getattr(v, "pose", v) for k, v in skip[b].items()})
    # poses good enough to subtract: tracked bones' guesses, and bones given or registered this frame
    known = {i for i, b in enumerate(names) if hist[b] or (f in skip[b] and i not in todo)}
    if seq_stage or seq_search or (joint and JOINT_KEYFRAMES):  # a keyframe of this frame stands for
        # the bone's guess (known: subtracted in the first frame too, until the bone is registered)
        for i in todo:
            kf = (run.keyframes.get(names[i]) or {}).get(f)
            kf = getattr(kf, "pose", kf)
            if kf is not None and np.all(np.isfinite(kf)):
                current[i] = np.asarray(kf, dtype=float)
                known.add(i)
    out: dict[int, Attempt] = {}
    work = {i: _Work() for i in todo}
    stage_others: dict = {}  # the neighbours each bone's last registration (its final stage) subtracted

    def others_of(i: int, cur: dict, kn: set):
        ids = [k for k in range(len(names)) if k != i and k in kn]
        return (np.stack([cur[k] for k in ids]), ids) if ids else None

    lockstep = (joint and o.lockstep and run.contacts is None and lockstep_applies(o.registration))
    # lockstep: each bone's search regions and the pose they were computed about, kept for the next
    # round when the bone's start moved within SAME_OPTIMUM of it (the regions reach 5 mm and 5°
    # beyond the search box; a search region costs 0.3 ms of host time)
    rois: dict[int, tuple] = {}

    def roi_of(i: int, start):
        hit = rois.get(i)
        return hit[1] if hit is not None and same_optimum(hit[0], start, bones[i].centroid) else None

    def side_of(rnd: int) -> list[int]:  # bones tracked from a guess (round 0: not a first frame)
        return [i for i in todo if (rnd > 0 and not FIRST_FRAME_AS_PASS) or hist[names[i]]]

    def start_of(i: int, rnd: int, cur: dict):
        """Where bone ``i``'s search starts in round ``rnd``: its guess in round 0 (and in every
        round with ``joint_restart`` or :data:`RESTART_FROM_PREDICTION`, a bone with a history), else
        its latest estimate."""
        if rnd == 0 or ((o.joint_restart or RESTART_FROM_PREDICTION) and hist[names[i]]):
            return guesses[i]
        return cur[i]

    def jobs_of(rnd: int, side: list[int], cur: dict, kn: set) -> list[JointJob]:
        starts = {i: start_of(i, rnd, cur) for i in side}
        return [JointJob(i, starts[i], bones[i].centroid, bones[i].outline, others_of(i, cur, kn),
                         roi_of(i, starts[i])) for i in side]

    def together(rnd: int, jobs: list[JointJob], idle=None, done=None) -> tuple[list, float]:
        t0 = time.perf_counter()
        if idle is None:  # the checks' motion limits while the device works on the searches' steps
            idle = limits_ahead([(hist[names[j.bone]], bones[j.bone].centroid, predicted[j.bone])
                                 for j in jobs], o, f)
        got = register_together(run.renderer, frame, jobs, staged(rnd, o.registration), profile=o.profile,
                                cancel=run.cancel, idle=idle, done=done)
        return got, (time.perf_counter() - t0) / len(jobs)

    def check(i: int, rnd: int, others, pre, host_only: bool = False):
        b = names[i]
        defer = defer_from <= rnd < rounds - 1
        first = not hist[b]
        if rnd == 0:
            opts, start = (o.first_options if first else o.registration), guesses[i]
        else:
            opts, start = o.registration, start_of(i, rnd, current)
        again = rnd > 0 and first and (not joint or FIRST_FRAME_AS_PASS)  # the first again (module docs)
        lock = adaptive and rnd == 1 and first  # joint's first-frame lockstep round (FIRST_FRAME_AGAIN_MOVED)
        if again:  # sequential's second pass (joint's first-frame second round: FIRST_FRAME_AS_PASS)
            opts, start = o.first_options, guesses[i]
        guess = guesses[i]
        kept = out.get(i)  # round 0's attempt (a first frame's second round; round 1's in the round after)
        flagged = kept is None or kept.result is None or bool(kept.flags)
        if rnd > 0 and first and (FIRST_FRAME_CHECK_FROM_ROUND0 or again or rnd > 1) and not flagged:
            guess = kept.result.pose  # checked from round 0's unflagged pose, not from the keyframe
        opts = staged(rnd, opts)
        near = nullcontext()
        stage_others[i] = others
        if seq_stage:
            from .final_stage import stage_neighbours

            stage_others[i] = others if others is not None else others_of(i, current, known)
            near = stage_neighbours(others_of(i, current, known))
        args = (run.renderer, frame, bones[i], i, start, guess, opts, o, state[b].scores, others, run.cancel,
                hist[b])
        kw = dict(verify=first and (rnd == 0 or again or (lock and flagged)),  # the second pass too
                  start_score=state[b].start_score, seed=f, frame_number=f, good_sigmas=state[b].sigmas,
                  reference=state[b].reference, host_only=host_only, defer_confidence=defer,
                  prediction=predicted[i])
        with near:
            got = None
            if rnd > 0 and stage_only and pre is None and first:  # the second pass: the stage alone (may)
                got = stage_pass(register_checked, kept, *args, **kw)
                if got is not None and not got.retried:
                    return got
            new = register_checked(*args, pre=pre, **kw)
            if got is not None:  # (the stage pass's work, its result dropped for a retry: counted too)
                new.evaluations += got.evaluations
                new.time_s += got.time_s
            return new

    rounds = o.joint_rounds if joint else 1
    if joint and FIRST_FRAME_SECOND_ROUND and any(not hist[names[i]] for i in todo):
        rounds = max(rounds, 2)  # a first frame: a second round (FIRST_FRAME_SECOND_ROUND)
    if (seq_stage or seq_search) and SEQUENTIAL_SECOND_PASS and any(not hist[names[i]] for i in todo):
        rounds = 2  # a first frame: a second pass (SEQUENTIAL_SECOND_PASS)

    def staged(rnd: int, opts: RegistrationOptions) -> RegistrationOptions:
        """The registration options of round ``rnd``: the final stage only in the last round."""
        if opts.final is None or rnd >= rounds - 1 or FINAL_EVERY_ROUND:  # (a round after it: AGAIN_MOVED)
            return opts
        return _replace(opts, final=None)

    # the confidence of a round before the last, mostly replaced by the next round's, when it is kept
    defer_from = rounds if run.contacts is not None else 0

    ahead = None  # (signature, jobs, results, seconds per job) of a round started before the checks
    adaptive = (joint and FIRST_FRAME_AGAIN_MOVED and not FIRST_FRAME_AS_PASS and rounds > 1
                and any(not hist[names[i]] for i in todo))
    plan = [(rnd, list(todo)) for rnd in range(rounds)]
    for rnd, these in plan:  # (a first frame's round after the last appended: FIRST_FRAME_AGAIN_MOVED)
        pre = {}
        checked: dict = {}
        before = dict(current)
        if lockstep:
            side = [i for i in side_of(rnd) if i in these]
            if len(side) > 1:
                if run.cancel():
                    return None
                jobs = jobs_of(rnd, side, current, known)
                if ahead is not None and ahead[0] == _signature(jobs):
                    _, jobs, got, spent = ahead  # started with these very jobs
                else:  # (a bone's checks, host work only, while the others' stages run: taken below)
                    t1 = time.perf_counter()

                    def early(k, res, rnd=rnd, jobs=jobs, side=side, checked=checked, t1=t1) -> None:
                        spent = (time.perf_counter() - t1) / len(jobs)
                        checked[side[k]] = check(side[k], rnd, jobs[k].others, (res, spent), host_only=True)

                    got, spent = together(rnd, jobs, done=early)
                ahead = None
                pre = {i: (r, job.others, spent) for i, r, job in zip(side, got, jobs, strict=True)}
                rois.update((job.bone, (job.initial_pose, job.roi)) for job in jobs if job.roi is not None)
                if AHEAD and rnd + 1 < rounds and len(side) == len(todo):
                    # the next round from the poses these checks leave when they pass (every bone's
                    # result, or its estimate where it fell outside a view), the checks meanwhile
                    cur, kn = dict(current), set(known)
                    for i in todo:
                        if not isinstance(pre[i][0], OutsideViewError):
                            cur[i] = pre[i][0].pose
                            kn.add(i)
                    nxt = jobs_of(rnd + 1, side_of(rnd + 1), cur, kn)
                    tasks = list(todo)

                    def idle(rnd=rnd, pre=pre, tasks=tasks, checked=checked) -> None:
                        if tasks:
                            i = tasks.pop(0)
                            checked[i] = check(i, rnd, pre[i][1], (pre[i][0], pre[i][2]), host_only=True)

                    sig = _signature(nxt)
                    got, spent = together(rnd + 1, nxt, idle)
                    while tasks:
                        idle()
                    ahead = (sig, nxt, got, spent)
        for i in these:
            if run.cancel():
                return None
            others = None
            if i in pre:
                others = pre[i][1]
            elif joint or seq_search:
                others = others_of(i, current, known)
            new = checked.get(i)
            if new is None:
                new = check(i, rnd, others, (pre[i][0], pre[i][2]) if i in pre else None)
            if run.contacts is not None and new.result is not None and not run.cancel.fired:
                done = [k for k in range(len(names)) if k != i and k in out and out[k].result is not None]
                if done:  # neighbours registered in this frame, not mere guesses
                    wide = not hist[names[i]] and (rnd == 0 or FIRST_FRAME_AS_PASS)  # registered with these
                    opts = o.first_options if wide else o.registration
                    keep_apart(run, frame, i, new, others, [(k, current[k]) for k in done], opts)
            if run.cancel.fired:  # the registration was cut short: nothing of this frame stands
                return None
            work[i].add(new)
            if new.result is None and i in out and out[i].result is not None:
                continue  # a later round lost the bone (outside a view): the earlier pose stands
            out[i] = new
            if new.result is not None:
                current[i] = new.result.pose
                known.add(i)
        if adaptive and rnd == rounds - 1:  # the bones whose neighbours moved: once more
            more = _moved_around(these, before, current, out, bones)
            if more:
                plan.append((rnd + 1, more))
    done = {}
    for i in todo:
        a = settle(out[i])
        if a.result is not None and o.registration.final is not None:  # the stage's move against the bone's
            moved = stage_move_check(a.result.timing, a.confidence, state[names[i]].moves, n=o.history,
                                     limit=o.stage_move_limit, sigmas=o.stage_move_sigmas,
                                     min_frames=o.stage_move_frames)
            if moved and STAGE_MOVE_CONFIRM:
                moved = _confirmed(run, frame, i, a, stage_others.get(i), work[i], moved)
            back = None
            if moved and o.stage_move_reject:
                from .final_stage import rejected

                back = rejected(a.result)
            if back is not None:  # the similarity's optimum stands (module docs)
                a.result = back
                moved = [f"{moved[0][:-1]}; final stage rejected: the similarity's pose kept)"]
            a.flags = a.flags + moved
        done[i] = _frame_result(names[i], f, a, work[i])
    return done


def _confirmed(run: _Run, frame, i: int, a: Attempt, others, w: _Work, moved: list) -> list:
    """:func:`core.tracking.stage_move.confirmed` with :data:`CONFIRM_FLOOR_MM` as it is now."""
    return confirmed(run, frame, i, a, others, w, moved, floor_mm=CONFIRM_FLOOR_MM)


def _moved_around(todo: list[int], before: dict, current: dict, out: dict, bones) -> list[int]:
    """The bones of ``todo`` left unflagged whose neighbours (of ``todo``) moved from ``before`` to
    ``current`` by more than :data:`FIRST_FRAME_MOVE_FLOOR` (:data:`FIRST_FRAME_AGAIN_MOVED`)."""
    from .checks import _distance

    mm, deg = FIRST_FRAME_MOVE_FLOOR
    moved = set()
    for k in todo:
        if k in before and k in current:
            dt, dr = _distance(before[k], current[k], bones[k].centroid)
            if dt > mm or dr > deg:
                moved.add(k)
    return [i for i in todo if out.get(i) is not None and out[i].result is not None and not out[i].flags
            and moved - {i}]


def _signature(jobs: list[JointJob]) -> tuple:
    """What a lockstep round's registrations depend on, per job (before it fills in its regions):
    the bone, its start, its neighbours' poses and the kept search regions, as bytes."""
    return tuple((j.bone, np.asarray(j.initial_pose, dtype=float).tobytes(),
                  None if j.others is None else (np.asarray(j.others[0], dtype=float).tobytes(),
                                                 tuple(j.others[1])),
                  None if j.roi is None else np.asarray(j.roi).tobytes()) for j in jobs)
