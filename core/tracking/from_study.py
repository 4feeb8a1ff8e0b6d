"""Tracking a :class:`core.study.Study` trial: frames, bone models, journal and report wired in.

:func:`track_study` reads the trial's two views frame by frame, turns raw camera frames into
flatfield-normalised fluence (:func:`frame_reader`), builds each bone's :class:`BoneModel` from
the study's CT (a bone whose CT has no voxel above the threshold is reported and left out; the
others are tracked), starts from the poses already in the trial's journal (keyframes), records
every registered frame with :meth:`core.study.Trial.record_pose` as it finishes, and keeps the
report ``results/reports/tracking/<trial>.json`` (summary, per-frame scores, evaluations,
confidence and review flags; under ``"options"`` the mode, the failure checks' thresholds,
:data:`core.tracking.options.CHECK_FIELDS`, ``"trajectory_limit"`` and ``"backward_limit"``, None
where that check is off) up to date — written when a frame is flagged, at least
every ``report_every_s`` seconds, and at the end. ``resume=True`` carries on an interrupted run from
the journal: the frames done keep their review state and enter the report as they were
(:func:`core.tracking.trial.journal_inputs`).

Frame normalisation, in order of precedence
-------------------------------------------
1. ``correction``: one callable per view, raw DN frame → fluence in [0, 1] (e.g. a
   :class:`core.imaging.Pipeline`);
2. the correction pipelines saved with the calibration version the trial uses
   (:func:`core.study.calibrations.trial_correction`, written by ``talus calibrate``);
3. the study settings ``"correction": {"views": [pipeline dict, ...]}``
   (:meth:`core.imaging.Pipeline.from_dict`);
4. otherwise frames are divided by the full scale ``2**bits - 1`` (no flatfield: noted in the
   report).

:func:`flatfield_corrected` tells from :func:`frame_reader`'s description which it was (cases 1–3
or 4): the one test of joint tracking in mode ``"auto"``, of the neighbours subtracted in
sequential tracking by default (``sequential_subtract`` None), of the likelihood final stage
(:func:`final_stage_problem`) and of ``talus batch``'s task grouping
(:func:`core.tracking.batch.tracks_jointly`).

The rig is the trial's calibration (:meth:`core.study.Trial.rig`), so a trial calibrated by
``talus calibrate`` is tracked with the saved rig and its saved correction.

Bone DRRs: attenuation in excess of the soft tissue
---------------------------------------------------
A bone in a radiograph sits in soft tissue: what its projection adds to the image is its
attenuation *over* that of the tissue it displaces, ``μ(HU) - μ(soft tissue)``, not ``μ(HU)``.
The default transfer (:func:`tissue_excess_transfer`) renders that excess above the bone
threshold. The plain thresholded transfer (``HUTransfer(threshold=...)``) adds ``μ`` of ~40 HU
tissue to every bone voxel, which weights trabecular bone (200–400 HU) almost as much as the
cortex and makes a 0.025 /mm step at the threshold — each trabecular voxel whose CT number
crosses it flickers in the DRR, edges the radiograph does not have. On the foot demo (256²,
frames 2–17, the talus registered from its true pose on flatfield-corrected frames, 2-core CPU)
the plain transfer left the talus 1.33° RMS off (mean −1.0° about the walking direction, the
Cramér–Rao bound is 0.21°), the excess transfer 0.86°, and with the tibia, calcaneus and
metatarsal subtracted at their poses (joint tracking) 0.48° (the plain transfer with
subtraction: 1.26°, and 0.31 mm instead of 0.10 mm: subtracted DRRs must match the image)).

The threshold also keeps the similarity's domain — the DRR's support — on the bone. Rendered
without one, a CT's soft tissue at ~40 HU with its noise adds a little to every ray through the
crop, so the domain becomes the whole projected crop and whatever the image has there that the
model lacks pulls the optimum: on the harder foot trial (:mod:`core.studies.tracking.hard_trial`,
one H200, 1024², 12 frames) the tibia was 0.51–0.66° RMS off about its long axis with the
excess transfer and no threshold, 0.26–0.38° with :func:`tissue_excess_transfer`. A transfer
without a threshold is therefore given bones cut out of their crop (``isolate_mm``).

Bones (mode)
------------
With ``options=None`` (or ``mode="auto"``) and frames normalised by a flatfield correction
(cases 1–3 above), several bones are tracked jointly: overlapping bones — the talus between the
tibia and the calcaneus — are then registered with their neighbours' DRRs subtracted. Frames
divided by the full scale only are not matched to the DRRs' intensities, so they are tracked one
bone at a time. ``mode="sequential"`` or ``"joint"`` is used as given.

Sequential tracking subtracts the neighbours in each bone's search
(``TrackingOptions.sequential_subtract``; the bones registered earlier in the frame at their poses,
the others at their keyframes of the frame or their guesses) when the frames are flatfield-corrected
and the option is None ("auto", the default): the same test. On the synthetic 1024² acceptance trial
(one NVIDIA H100, 100 frames; :mod:`core.studies.tracking.sequential_drift`) it took the sequential
run's silent frames over 4× the bound (tibia/talus/calcaneus) from 9/7/0 to 0/0/0 on seed 0, 9/0/0
to 8/0/0 and 4/1/0 to 2/0/0 on seeds 1 and 2 (joint tracking: 1/0/0, 7/0/0, 2/0/0). Frames divided
by the full scale are searched against the whole image (on the wrist sample's 8-bit radiographs
subtraction pulled the radius into the ulna's hole); True or False is used as given. The report's
``"options"`` say what the searches did (``"sequential_subtract"``, sequential runs only): false
where one bone is tracked (``talus batch --split-bones`` tasks), whose search has nothing to
subtract, with ``"sequential_subtract_note"`` saying so when the choice was on.

On resume (``resume=True`` with tracking results of the range in the journal) auto keeps what the
searches of the frames already tracked did, so that one trial is not tracked by two methods: the
choice the run being resumed recorded in its report (``"options"``; written as the run starts), off
where it recorded none — a run from before the neighbours were subtracted by default. Without that
report (a ``talus batch --split-bones`` task's or a range's report is named after its bone or frames),
the trial's other sequential reports of the bones tracked decide where they agree — ``--split-bones``
tasks tracked each bone alone: off; where they disagree or none exists, auto decides as for a new run
(the earlier frames' method is unknown). ``"sequential_subtract_note"`` says which and why. A range
whose only tracked frame is the keyframe it starts from, tracked by the range beside it that starts
there too (a fresh ``talus batch --ranges`` run; that range's report reaches outside this one),
resumes nothing: auto as for a new run, no note (such a range's record said "resumed … as the
trial's earlier runs did: walk.1-0"). A joint
run's report, or nothing tracked yet, leaves auto as for a new run; True or False still win. The
report lists the bones tracked (``"bones"``). A joint run's ``"options"`` record ``"joint_rounds"``
and ``"joint_restart"`` (``TrackingOptions.joint_rounds``, ``.joint_restart``, used as given), with
``"joint_restart_note"`` where a resumed run uses other rounds or the other restart choice than the
run being resumed recorded (a report without ``"joint_rounds"`` ran two: the default before).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import replace

import numpy as np

from ..render import HUTransfer
from .bones import bone_model
from .flags_post import journal_neighbours
from .options import CHECK_FIELDS, STAGE_MOVE_FIELDS
from .results import FrameResult
from .trial import TrackingOptions, TrackingResult, journal_inputs, track

__all__ = ["FULL_SCALE", "TRACK_COMMAND", "WINDOW_TRACKING", "FinalStageError", "final_stage_problem",
           "flatfield_corrected", "frame_reader", "tissue_excess_transfer", "track_study"]

#: CT number of the soft tissue around bones (muscle, tendon, fat-free tissue: 40 HU).
SOFT_TISSUE_HU = 40.0
#: :func:`frame_reader`'s description of frames divided by the full scale only (no flatfield).
FULL_SCALE = "full scale (no flatfield)"
#: Rim (mm) kept around each bone (:func:`core.tracking.bones.bone_model`'s ``isolate_mm``) when
#: the transfer has no threshold.
ISOLATE_MM = 1.0


def tissue_excess_transfer(threshold_hu: float = 200.0, *, soft_tissue_hu: float = SOFT_TISSUE_HU,
                           mu_water: float = HUTransfer.mu_water) -> HUTransfer:
    """HU → μ of a bone DRR for tracking: ``μ(HU) - μ(soft_tissue_hu)`` (the linear model at
    ``mu_water``, 1/mm) for voxels at or above ``threshold_hu``, 0 below (see the module docs)."""
    hi = 3000.0
    return HUTransfer(mu_water=mu_water, threshold=float(threshold_hu),
                      curve=((-1000.0, float(soft_tissue_hu), hi),
                             (0.0, 0.0, mu_water * (hi - soft_tissue_hu) / 1000.0)))


def frame_reader(study, trial, *, correction: Sequence[Callable] | None = None) -> tuple[Callable, str]:
    """``(read(frame) -> [fluence per view], description)`` for a study trial (see the module
    docs for how raw frames are normalised). A view whose frame cannot be read gives None; each
    view is read alone (a damaged file in one leaves the other's image). ``read.reason(frame,
    view)`` says why (the file and the reader's error; the frame source's hook of
    :func:`core.tracking.trial.track`, whose frame flag then names the view, the file and the
    error — it said only 'frame missing in view 0, 1'), and ``read.unreadable`` maps such a frame
    to the same for all its views ("view 2: <file>: <error>"; a frame the trial's index cannot give:
    "frame N of the trial cannot be read: <error>", every view's reason)."""
    rig = trial.rig()
    how = "given"
    fns = list(correction) if correction is not None else None
    if fns is None:
        from ..study.calibrations import trial_correction

        fns = trial_correction(study, trial.name)
        how = f"saved with calibration {trial.calibration}"
    if fns is None and isinstance(study.settings.get("correction"), dict):
        from ..imaging.pipeline import Pipeline

        fns = [Pipeline.from_dict(d) for d in study.settings["correction"]["views"]]
        how = "study settings"
    if fns is None:
        bits = [v.get("bit_depth") or 16 for v in study.manifest["trials"][trial.name]["views"]]
        fns = [lambda raw, b=b: np.clip(np.asarray(raw, np.float32) / (2**b - 1), 0, 1) for b in bits]
        how = FULL_SCALE
    if len(fns) != len(rig):
        raise ValueError(f"correction: expected {len(rig)} per-view corrections, got {len(fns)}")

    unreadable: dict[int, str] = {}
    reasons: dict[int, dict[int, str]] = {}  # frame -> view -> why it cannot be read

    def read(t: int):
        reasons.pop(t, None)
        unreadable.pop(t, None)
        try:
            seq = trial.sequences()
            index = seq.view_frames(t)
        except (ValueError, OSError, IndexError) as exc:  # the whole frame: one reason for every view
            unreadable[t] = f"frame {t} of the trial cannot be read: {exc}"
            reasons[t] = dict.fromkeys(range(len(rig)), unreadable[t])
            return [None] * len(rig)
        out, why = [], {}
        for v, (fn, view, k) in enumerate(zip(fns, seq.views, index, strict=True)):
            try:
                raw = view[k]
            except (ValueError, OSError, IndexError) as exc:  # a damaged file names itself
                out.append(None)
                why[v] = str(exc)
                continue
            out.append(None if raw is None else np.asarray(fn(raw), dtype=np.float32))
        if why:
            reasons[t] = why
            unreadable[t] = "; ".join(f"view {v + 1}: {r}" for v, r in why.items())
        return out

    read.unreadable = unreadable
    read.reason = lambda t, v: reasons.get(t, {}).get(v)
    return read, how


#: What holds the journals of a ``talus track`` run (``track_study``'s default ``lock_by``).
TRACK_COMMAND = "talus track"
#: What holds them while the window's tracking job runs.
WINDOW_TRACKING = "the window's tracking job"


def flatfield_corrected(how: str) -> bool:
    """Whether :func:`frame_reader`'s description ``how`` (also the tracking report's
    ``"normalisation"``) is of frames normalised by a flatfield correction — a given correction,
    the pipelines saved with the trial's calibration or the study settings' — rather than divided
    by the full scale only (:data:`FULL_SCALE`)."""
    return how != FULL_SCALE


class FinalStageError(ValueError):
    """The likelihood final stage asked for on a trial whose frames are not flatfield-corrected
    (:func:`final_stage_problem`'s message); raised by :func:`track_study` before any work."""


def _final_stage_note(trial_name: str, how: str) -> str | None:
    if flatfield_corrected(how):
        return None
    return (f"trial {trial_name!r}: its frames are not flatfield-corrected (divided by the full scale only), "
            "and the likelihood final stage compares DRRs with the line integrals of flatfield-normalised "
            "frames; calibrate the trial (the calibration wizard or talus calibrate), add a flatfield "
            "correction to the study settings, or track without the final stage")


def final_stage_problem(study, trial_name: str, *,
                        correction: Sequence[Callable] | None = None) -> str | None:
    """Why the likelihood final stage (``TrackingOptions.refine_likelihood``) cannot run on trial
    ``trial_name`` of ``study``, or None. The stage fits DRRs to the line integrals ``-log`` of the
    flatfield-normalised fluence (its weights are the expected counts): frames that are only
    divided by the full scale — no flatfield correction saved with the trial's calibration or in
    the study settings (:func:`frame_reader`) — do not give them. :func:`track_study` refuses such
    a trial with this message (:class:`FinalStageError`) before it locks or reads anything else."""
    _, how = frame_reader(study, study.trial(trial_name), correction=correction)
    return _final_stage_note(trial_name, how)


def _earlier_runs(study, trial_name: str, report_name: str, bones: set,
                  within: set | None = None) -> list[tuple[str, bool, str]]:
    """``(report name, subtracted, why not)`` of the trial's other sequential tracking reports of
    ``bones`` (``<trial>.json``, ``talus batch`` tasks' ``<trial>.<bone>.json`` and range reports):
    what their searches did — not where the run tracked one bone (``--split-bones`` tasks) or
    recorded no choice (a run from before the neighbours were subtracted by default). Joint runs'
    reports and other bones' are left out, and with ``within`` (frames) those whose frames reach
    outside them."""
    from ..study.errors import StudyError

    out = []
    for name in study.report_names("tracking"):
        if name == report_name or not (name == trial_name or name.startswith(trial_name + ".")):
            continue
        try:
            rep = study.read_report("tracking", name)
        except StudyError:
            continue
        opts = rep.get("options") if isinstance(rep, dict) else None
        if rep.get("trial") != trial_name or not isinstance(opts, dict) or opts.get("mode") == "joint":
            continue
        done = rep.get("frames_done") if isinstance(rep.get("frames_done"), list) else []
        seen = rep.get("bones") if isinstance(rep.get("bones"), list) else [
            d.get("bone") for d in done if isinstance(d, dict)]
        if not bones & set(seen):
            continue
        span = rep.get("frames")
        if within is not None and not (isinstance(span, list) and len(span) == 2 and all(
                isinstance(f, int) for f in span) and set(range(min(span), max(span) + 1)) <= within):
            continue
        got = opts.get("sequential_subtract")
        why = ("" if got is True else "one bone" if len(set(seen)) == 1
               else "off" if got is False else "no choice recorded")
        out.append((name, got is True, why))
    return out


def _rounds_words(rounds: int, restart: bool, *, both: bool) -> str:
    """``"2 joint rounds, joint restart on"`` (``both``), else the part that differs."""
    return f"{rounds} joint round{'s' if rounds != 1 else ''}" + (
        f", joint restart {'on' if restart else 'off'}" if both else "")


def _resumed_restart(study, report_name: str, restart: bool, skip: dict, rounds: int = 2) -> str | None:
    """The note of a joint run resumed with another ``joint_restart`` or ``joint_rounds`` than the
    joint run being resumed recorded in its report (restart off and 2 rounds where it recorded none:
    the defaults before), else None (also with no tracking result in the journal, ``skip``): its
    frames were tracked by the other choice (the options are used as given)."""
    from ..study.errors import StudyError

    if not any(isinstance(r, FrameResult) for done in skip.values() for r in done.values()):
        return None

    try:
        old = study.read_report("tracking", report_name)
    except StudyError:  # none, or unreadable
        return None
    opts = old.get("options") if isinstance(old, dict) else None
    if not isinstance(opts, dict) or opts.get("mode") != "joint":
        return None
    was_restart, was_rounds = bool(opts.get("joint_restart")), opts.get("joint_rounds", 2)
    if was_rounds == rounds:
        if was_restart == restart:
            return None
        return (f"resumed with joint restart {'on' if restart else 'off'}: the frames tracked before ran "
                f"with it {'off' if restart else 'on'}")
    both = was_restart != restart
    return (f"resumed with {_rounds_words(rounds, restart, both=both)}: the frames tracked before ran with "
            f"{_rounds_words(was_rounds, was_restart, both=both)}")


def _resumed_subtract(study, trial_name: str, report_name: str, skip: dict,
                      shared: frozenset = frozenset(), frames=()) -> tuple[bool | None, str | None]:
    """``sequential_subtract`` auto on resume: ``(choice, note)`` — what the searches of the frames
    already tracked did, so that a trial is not tracked by two methods: as the run being resumed
    recorded in its report (``"options"``; off where it recorded none: a run from before the
    neighbours were subtracted by default); without such a report, as the trial's other tracking
    reports of the bones tracked say where they agree (:func:`_earlier_runs`). ``(None, why)``:
    they disagree, or no report says — auto as for a new run, ``why`` for the note. ``(None,
    None)``: nothing tracked to carry on (no tracking result of the range in the journal) or a
    joint run's report (the user changed the mode): auto as for a new run, no note. ``shared``:
    ``(bone, frame)`` the range ``frames`` starts from, a keyframe a neighbouring range may start
    from too — tracked there, by the other range of a fresh ``talus batch --ranges`` run: without the
    run's own report, where only such frames are tracked, only reports of frames within the range
    count (an earlier run of it that reached no further); none: auto as for a new run, no note."""
    tracked = {b for b, done in skip.items() if any(isinstance(r, FrameResult) for r in done.values())}
    if not tracked:
        return None, None
    from ..study.errors import StudyError

    try:
        old = study.read_report("tracking", report_name)
    except StudyError:  # none, or unreadable
        old = None
    opts = old.get("options") if isinstance(old, dict) else None
    opts = opts if isinstance(opts, dict) else {}
    if opts.get("mode") == "joint":
        return None, None
    got = opts.get("sequential_subtract")
    if isinstance(got, bool):
        return got, (f"resumed: neighbours {'' if got else 'not '}subtracted, as the run being resumed "
                     f"recorded (auto)")
    if isinstance(old, dict):
        return False, ("resumed: neighbours not subtracted (auto): the run being resumed recorded no choice "
                       "(tracked before they were subtracted by default)")
    # only the keyframe it starts from tracked: by an earlier run of this range (one that reached no
    # further, its frames within the range), or by the range beside that starts there too (no resume)
    start_only = not any(isinstance(r, FrameResult) and (b, f) not in shared
                         for b, done in skip.items() for f, r in done.items())
    runs = _earlier_runs(study, trial_name, report_name, tracked,
                         within={int(f) for f in frames} if start_only else None)
    if start_only and not runs:
        return None, None
    if not runs:
        return None, ("no tracking report of the trial says how its frames tracked before were searched "
                      "(their method is unknown)")
    said = [f"{n}{f' ({why})' if why else ''}" for n, _, why in runs]
    if len({c for _, c, _ in runs}) == 2:
        return None, f"the trial's earlier runs differ: {', '.join(said)}"
    got = runs[0][1]
    return got, (f"resumed: neighbours {'' if got else 'not '}subtracted (auto), as the trial's earlier "
                 f"runs did: {', '.join(said)}")


def track_study(study, trial_name: str, bones: Sequence[str] | None = None,
                frames: Sequence[int] | None = None, *, options: TrackingOptions | None = None,
                device: str | None = None, resume: bool = False,
                threshold_hu: float = 200.0, transfer: HUTransfer | None = None,
                correction: Sequence[Callable] | None = None, progress=None, cancel=None,
                report_every_s: float = 5.0,
                report_name: str | None = None,
                lock_by: str = TRACK_COMMAND) -> tuple[TrackingResult | None, dict]:
    """Track ``bones`` of trial ``trial_name`` over ``frames`` (default all, forward).

    ``study`` must be open for writing. Returns ``(result, report)``; ``result`` is None when no
    bone could be tracked (the report says why). Bones whose CT has no bone above
    ``threshold_hu`` are listed under ``report["stopped"]`` with the reason.

    Bones are tracked jointly when ``options`` is None (or its mode ``"auto"``) and the frames
    are flatfield-corrected, else as ``options`` say; tracked sequentially, each bone's search
    subtracts its neighbours when the frames are flatfield-corrected and
    ``options.sequential_subtract`` is None (auto; on resume the choice the run being resumed
    recorded), as given otherwise (see the module docs and
    :mod:`core.tracking.trial`: joint tracking needs DRR intensities matched to the
    radiographs). ``transfer`` defaults to :func:`tissue_excess_transfer` at ``threshold_hu``; with
    a transfer that has no threshold, voxels farther than :data:`ISOLATE_MM` from each bone are set to
    air (the module docs say why).

    The likelihood final stage (``options.refine_likelihood``) on frames that are not
    flatfield-corrected raises :class:`FinalStageError` (:func:`final_stage_problem`'s message)
    first. The bones' journals are locked next (:meth:`core.study.Study.lock_journal`, the lock's
    holder line saying ``lock_by``: what tracks them, named in a refused hand edit's message): a bone
    another process is tracking raises :class:`~core.io.atomic.LockedError` before any work.
    The report is ``results/reports/tracking/<report_name>.json`` (default: the trial's name;
    ``talus batch`` gives each (trial, bone) task its own).
    """
    from ..render import DRRRenderer

    trial = study.trial(trial_name)
    names = list(trial.bones if bones is None else bones)
    for b in names:
        if b not in trial.bones:
            raise ValueError(f"bones: trial {trial_name!r} has no bone {b!r} (has {list(trial.bones)})")
    read, how = frame_reader(study, trial, correction=correction)  # read once: the refusal and the mode
    if options is None:
        options = TrackingOptions(mode="auto")
    likelihood = "likelihood" in (options.registration.final, getattr(options.first, "final", None))
    if likelihood:
        problem = _final_stage_note(trial_name, how)
        if problem:
            raise FinalStageError(problem)
    for b in names:
        study.lock_journal(trial_name, b, by=lock_by)
    report_name = trial_name if report_name is None else report_name
    n = trial.n_frames
    order = list(range(n) if frames is None else frames)
    bad = [f for f in order if not 0 <= f < n]
    if bad:
        raise ValueError(f"frames: {bad[:3]} outside the trial's 0..{n - 1}")
    stopped, models = {}, []
    # a transfer without a threshold renders the crop's soft tissue and CT noise: keep the bones alone
    isolate = ISOLATE_MM if (transfer is not None and transfer.threshold is None) else None
    for b in names:
        try:
            models.append(bone_model(study.bone_volume(b), name=b, threshold=threshold_hu, mesh=False,
                                     isolate_mm=isolate))
        except ValueError as exc:
            stopped[b] = str(exc)
    states = {m.name: trial.results(m.name) for m in models}
    existing, skip = journal_inputs(states, order, resume=resume)
    for m in list(models):
        if not (existing[m.name] or skip[m.name]):
            stopped[m.name] = "no keyframe: record a starting pose for this bone first"
            models.remove(m)
    if options.mode == "auto":  # flatfield-corrected frames: subtract the neighbours
        joint = len(models) > 1 and flatfield_corrected(how)
        options = replace(options, mode="joint" if joint else "sequential")
    subtract_note = None
    if options.mode == "sequential" and options.sequential_subtract is None:  # auto: the same test
        resumed = resume and len(models) > 1  # one bone: nothing to subtract, nothing to keep
        shared = frozenset((b, order[0]) for b in skip if order and order[0] in states[b].keyframes)
        kept, subtract_note = (_resumed_subtract(study, trial_name, report_name, skip, shared, order)
                               if resumed else (None, None))
        auto = flatfield_corrected(how) if kept is None else kept
        if kept is None and subtract_note:  # resumed, the earlier frames' method not known
            subtract_note = (f"resumed: neighbours {'' if auto else 'not '}subtracted (auto, as for a new "
                             f"run): {subtract_note}")
        options = replace(options, sequential_subtract=auto)
    report = {"trial": trial_name, "bones": [m.name for m in models],
              "frames": [order[0], order[-1]] if order else [], "normalisation": how,
              "stopped": stopped, "options": {"resume": resume,
                                              "mode": options.mode,
                                              "checks": {k: getattr(options, k) for k in CHECK_FIELDS},
                                              "trajectory_limit": options.trajectory_limit,
                                              "backward_limit": options.backward_limit}}
    if options.mode == "sequential":  # whether each bone's search subtracted its neighbours
        # (one bone tracked: nothing to subtract, whatever the choice)
        report["options"]["sequential_subtract"] = bool(options.sequential_subtract) and len(models) > 1
        if options.sequential_subtract and len(models) < 2:
            subtract_note = "on, but no other bone tracked: nothing to subtract"
        if subtract_note:
            report["options"]["sequential_subtract_note"] = subtract_note
    if options.mode == "joint":  # the rounds, and those after the first from the prediction (joint_restart)
        report["options"]["joint_rounds"] = int(options.joint_rounds)
        report["options"]["joint_restart"] = bool(options.joint_restart)
        note = _resumed_restart(study, report_name, options.joint_restart, skip,
                                options.joint_rounds) if resume else None
        if note:
            report["options"]["joint_restart_note"] = note
    if likelihood:  # the final stage's move check flagged (or rejected) with these
        report["options"]["stage_move_check"] = {k: getattr(options, k) for k in STAGE_MOVE_FIELDS}
    if not models:
        report["summary"] = {"status": "stopped", "message": "no bone to track"}
        study.write_report("tracking", report_name, report)
        return None, report
    tr = transfer or tissue_excess_transfer(threshold_hu)
    renderer = DRRRenderer(trial.rig(), [m.volume for m in models], transfer=tr, device=device)
    state = {"last": time.monotonic(), "frames": []}

    def write(result_frames, summary=None):
        rep = dict(report, frames_done=result_frames)
        if summary:
            rep["summary"] = summary
        study.write_report("tracking", report_name, rep)

    def on_progress(done, total, fr):
        state["frames"].append(fr.to_dict())
        now = time.monotonic()
        if fr.flags or now - state["last"] > report_every_s:
            write(state["frames"])
            state["last"] = now
        if progress is not None:
            progress(done, total, fr)

    write([])  # the choices recorded from the start: a resume reads them (_resumed_subtract)
    result = track(renderer, models, read, order, keyframes=existing, options=options,
                   record_result=lambda fr: trial.record_pose(fr.bone, fr.frame, fr.pose, score=fr.score,
                                                              tracking=fr.journal_fields()),
                   skip=skip, progress=on_progress, cancel=cancel,
                   neighbours=journal_neighbours(states, order))  # the trajectory check's, outside the range
    report["summary"] = result.summary()
    report["flagged"] = [r.to_dict() for r in result.flagged]
    # the frames as the run left them: the trajectory post-pass flags after the progress events
    done = [result.results[k].to_dict() if (k := (d.get("bone"), d.get("frame"))) in result.results else d
            for d in state["frames"]]
    write(done, report["summary"])
    return result, report
