"""Tracking many trials of many studies as independent tasks, on Dask distributed (``talus batch``).

A *task* is one trial's bone, or one trial's bones tracked together — jointly (``mode="joint"``)
or one after another in each frame, each with the others' DRRs subtracted (``mode="sequential"``)
— of one study (:class:`BatchTask`, from :func:`build_tasks`), over the whole trial or, with
``ranges=True``, over one frame range between the bone's keyframes (:func:`keyframe_ranges`).
Which follows ``mode``, so that a batch tracks a trial as ``talus track --mode`` does:

* ``"auto"`` (the default): a trial whose frames are flatfield-corrected — by the correction
  pipelines saved with its calibration (``talus calibrate``) or those of the study settings —
  is one joint task of its bones, any other trial one task per bone
  (:func:`tracks_jointly`: the test :func:`core.tracking.from_study.track_study` makes for
  ``TrackingOptions(mode="auto")``, so a batch tracks a trial as ``talus track`` does). Bones
  that overlap in the views — the foot demo's talus between the tibia and the calcaneus — are
  then registered with their neighbours' DRRs subtracted, which a task of one bone cannot do
  (on the 512² foot demo one bone at a time lost the talus: the numbers are in
  :mod:`core.tracking.trial`'s notes); frames divided by the full scale only do not match the
  DRRs' intensities: their bones are searched alone (``sequential_subtract`` auto is off there)
  and do not depend on each other, so they are tracked one per task, side by side — unless
  ``subtract=True`` (``--sequential-subtract on``) asks for the neighbours subtracted, which
  makes one sequential task of the trial's bones, as ``talus track`` tracks them;
* ``"joint"``: one joint task per trial, whatever its frames;
* ``"sequential"``: one task per trial, its bones tracked one after another in each frame with
  the others' DRRs subtracted (``TrackingOptions.sequential_subtract``, auto: on for
  flatfield-corrected frames) — what ``talus track --mode sequential`` does, with its poses. With
  ``split_bones=True`` (``--split-bones``) one task per (trial, bone) instead: more tasks to
  spread over the workers, but a task of one bone has no neighbour to subtract, so each bone is
  searched against the whole image (its record and report say so). Grouped is the default because
  a user who asks for sequential tracking expects the trial tracked as ``talus track`` tracks it:
  on the acceptance trial searching each bone against the whole image left 16 of 21 frames over
  4× the Cramér–Rao bound unflagged, with the neighbours subtracted 3, all flagged (README,
  *Tracking: accuracy and speed*); trials, and frame ranges (``ranges=True``), still spread a
  batch over the workers.

Each task's record says what its searches did: ``mode`` (joint or sequential) and, for a
sequential task, ``sequential_subtract`` — the choice that ran, auto resolved to True or False
(False for a task of one bone, ``sequential_subtract_note`` then saying why where the choice was
on) — as its tracking report's ``"options"`` do. A task run again (resume) keeps the choice its
report recorded (:func:`core.tracking.from_study.track_study`). A joint task's record says its rounds
per frame (``joint_rounds``, ``TrackingOptions.joint_rounds``, 1 by default) and whether its rounds
after the first started from the prediction (``joint_restart``, ``TrackingOptions.joint_restart``),
both given in :attr:`TaskSettings.options` and used as given on resume; ``joint_restart_note`` where
the frames it resumes ran with other rounds or the other restart choice.

A task runs :func:`run_task`: it opens its study for writing, which locks only the journals of
its bones (:meth:`core.study.Study.lock_journal`), and calls
:func:`core.tracking.from_study.track_study` — what ``talus track`` calls — with
``resume=True``, so every registered frame is in the study's journal as soon as it finishes and
a task that runs again (after its worker was killed, or in a later batch) carries on from the
journal: nothing is lost but the frame in flight, and the poses are those of an uninterrupted
run (each registration is seeded from its frame number). Each task writes its own tracking
report, ``results/reports/tracking/<trial>.<bone>.json`` (``<trial>.json`` for a task of several
bones, as ``talus track`` writes for the trial; ``.<first>-<last>`` before ``.json`` for a frame range).

Frame ranges
------------
A bone with hand-set keyframes ``k0 < k1 < ... < km`` in the tracked frames ``[lo, hi)`` splits
into ranges that start at a keyframe: ``k0`` backward to ``lo``, then ``k0`` forward to
``k1 - 1``, ``k1`` forward to ``k2 - 1``, ..., ``km`` forward to ``hi - 1`` (a joint group splits
at the frames where every bone of it has a keyframe). Each range is tracked from its own
keyframe, so the ranges of one bone run side by side on different workers and give the poses a
serial run of the same ranges gives (the first frame of every range is the keyframe itself; the
frame ``k0``, in two ranges, is registered from the same inputs by both). Tasks of one bone's
ranges write one journal: each record takes the journal's lock for its append only
(:mod:`core.tracking.batch_journal`), so a range task waits for another's append but is refused at its start
when another writer holds the bone for good (``talus track``, or the window). Only
``guess="velocity"`` or ``"previous"`` suit ranges: a spline guess would read other ranges'
results as knots. Each range task's trajectory check (:mod:`core.tracking.flags_post`) fits
through the poses other ranges had journaled when it started; once every range of a trial's bone
(group) is complete, :func:`trajectory_pass` judges all of their frames again in one pass, so the
review flags — the keyframe two ranges share included — do not depend on the order the tasks ran;
the journal, the ranges' reports and the summary's task records then give the flags after that
pass (:mod:`core.tracking.batch_pass`; the summary's ``trajectory_pass`` lists what it judged and
changed).

:func:`run_batch` submits the tasks to a Dask cluster — a local one by default
(:func:`local_cluster`: one worker process per GPU, its ``CUDA_VISIBLE_DEVICES`` set to that GPU
and a ``GPU`` worker resource, or one single-threaded worker process per CPU core group without a
GPU), or an existing scheduler — retries a failed task once (an exception, or its worker dying:
Dask's ``allowed-failures`` is set to 1 for the local cluster), follows the tasks' frames through
worker events, and returns a JSON-ready summary (:func:`summarize`); both live in
:mod:`core.tracking.batch_dask` and are importable from here. Nothing here imports Qt;
``dask[distributed]`` is the optional ``batch`` extra, imported only by :func:`run_batch` and
:func:`local_cluster`.
"""

from __future__ import annotations

import itertools
import os
import socket
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .batch_pass import final_records

__all__ = [
    "EVENT_TOPIC",
    "MODES",
    "BatchTask",
    "TaskSettings",
    "build_tasks",
    "keyframe_ranges",
    "local_cluster",  # noqa: F822 (from batch_dask, through __getattr__)
    "run_batch",  # noqa: F822
    "run_serial",
    "run_task",
    "summarize",
    "tracks_jointly",
    "trajectory_pass",
]

EVENT_TOPIC = "talus-batch"  # worker events: task start, frame done, task end
#: How :func:`build_tasks` groups a trial's bones into tasks (see the module notes).
MODES = ("auto", "joint", "sequential")


@dataclass(frozen=True)
class BatchTask:
    """One unit of work: ``bones`` of ``trial`` in the study at ``study`` (an absolute folder).

    More than one bone is a bone group, tracked as ``mode`` says: ``"joint"`` (None, the default,
    for a group) or ``"sequential"`` (one bone after another in each frame, the others' DRRs
    subtracted as ``TrackingOptions.sequential_subtract`` says); one bone is tracked alone
    (:attr:`tracking_mode`). ``frames`` is ``(first, last)``, both tracked, in tracking order
    (``first > last``: backward) for a frame range; None for the batch's frames
    (:attr:`TaskSettings.frames`)."""

    study: str
    trial: str
    bones: tuple[str, ...]
    frames: tuple[int, int] | None = None
    mode: str | None = None

    def __post_init__(self) -> None:
        if self.mode not in (None, "joint", "sequential"):
            raise ValueError(f"mode: expected None, 'joint' or 'sequential', got {self.mode!r}")

    @property
    def tracking_mode(self) -> str:
        """``"joint"`` or ``"sequential"``: the ``TrackingOptions.mode`` the task tracks with."""
        return self.mode or ("joint" if len(self.bones) > 1 else "sequential")

    @property
    def order(self) -> list[int] | None:
        """The frames of a range in tracking order (None: not a range)."""
        if self.frames is None:
            return None
        a, b = (int(x) for x in self.frames)
        return list(range(a, b + 1)) if a <= b else list(range(a, b - 1, -1))

    @property
    def key(self) -> str:
        """``<study folder name>/<trial>/<bone>[+<bone>...][:<first>-<last>]``: unique within a
        batch."""
        span = "" if self.frames is None else f":{self.frames[0]}-{self.frames[1]}"
        return f"{Path(self.study).name}/{self.trial}/{'+'.join(self.bones)}{span}"

    @property
    def report_name(self) -> str:
        """The task's tracking report (``results/reports/tracking/<report_name>.json``):
        ``<trial>.<bone>`` for one bone, ``<trial>`` for a group, joint or sequential (the report
        ``talus track`` writes for the trial), ``.<first>-<last>`` added for a frame range."""
        span = "" if self.frames is None else f".{self.frames[0]}-{self.frames[1]}"
        return f"{self.trial}{'' if len(self.bones) > 1 else '.' + self.bones[0]}{span}"


@dataclass(frozen=True)
class TaskSettings:
    """How every task tracks (the ``talus track`` options that apply to a whole batch)."""

    device: str | None = None  # Warp device; None: CUDA when the worker has a GPU, else CPU
    metric: str = "gc"
    guess: str = "velocity"
    threshold_hu: float = 200.0
    confidence: bool = True
    max_uncertainty: tuple[float, float] | None = None
    frames: tuple[int, int] | None = None  # [start, stop) of every trial; None: all frames
    options: tuple[tuple[str, Any], ...] = ()  # other TrackingOptions fields, as (name, value)

    def tracking_options(self, joint: bool):
        """The :class:`~core.tracking.trial.TrackingOptions` ``talus track --mode joint`` (``joint``)
        or ``--mode sequential`` builds."""
        from .cost import metric_terms
        from .options import DEFAULT_SEARCH
        from .register import RegistrationOptions
        from .trial import TrackingOptions

        reg = RegistrationOptions(terms=metric_terms(self.metric), bounds=(5.0, 5.0), sigma=(1.0, 1.0),
                                  search=DEFAULT_SEARCH)
        kw = dict(registration=reg, guess=self.guess, confidence=self.confidence,
                  max_uncertainty=self.max_uncertainty)
        kw.update(dict(self.options))  # e.g. the window's own registration options
        kw["mode"] = "joint" if joint else "sequential"
        return TrackingOptions(**kw)


def keyframe_ranges(keyframes: Sequence[int], start: int, stop: int) -> list[tuple[int, int]]:
    """The frame ranges of ``[start, stop)`` between ``keyframes``, each ``(first, last)`` in
    tracking order from a keyframe (see the module notes): ``k0`` back to ``start``, then from
    every keyframe forward to the frame before the next one (the last to ``stop - 1``). Without
    a keyframe in ``[start, stop)``: the whole range forward, ``[(start, stop - 1)]``.

    >>> keyframe_ranges([3, 10], 0, 20)
    [(3, 0), (3, 9), (10, 19)]
    """
    if not 0 <= start < stop:
        raise ValueError(f"frames: expected 0 <= start < stop, got {start}:{stop}")
    ks = sorted({int(k) for k in keyframes if start <= int(k) < stop})
    if not ks:
        return [(start, stop - 1)]
    out = [(ks[0], start)] if ks[0] > start else []
    out += [(a, b - 1) for a, b in itertools.pairwise(ks)]
    return [*out, (ks[-1], stop - 1)]


def tracks_jointly(study, trial: str) -> bool:
    """Whether ``mode="auto"`` tracks the bones of ``trial`` (in ``study``, a
    :class:`core.study.Study`) jointly: its frames are normalised by a flatfield correction — the
    pipelines saved with the trial's calibration, or the study settings' — rather than divided
    by the full scale. The test :func:`core.tracking.from_study.track_study` makes
    (:func:`~core.tracking.from_study.flatfield_corrected`) of the frame normalisation
    :func:`core.tracking.from_study.frame_reader` finds (it reads the correction
    pipelines, a few tens of ms for a 512² calibration).

    Raises
    ------
    StudyError
        A saved correction pipeline that cannot be read (as tracking the trial would).
    """
    from .from_study import flatfield_corrected, frame_reader

    _, how = frame_reader(study, study.trial(trial))
    return flatfield_corrected(how)  # track_study's own test of mode "auto"


def build_tasks(studies: Sequence[str | os.PathLike], trials: Sequence[str] | None = None,
                bones: Sequence[str] | None = None, *, mode: str = "auto", joint: bool | None = None,
                ranges: bool = False, frames: tuple[int, int] | None = None, split_bones: bool = False,
                subtract: bool | None = None) -> list[BatchTask]:
    """The tasks of ``studies``: every trial (or those named in ``trials``) × every bone of it
    (or those named in ``bones``), grouped by ``mode`` (:data:`MODES`, see the module notes):
    ``"auto"`` (the default) one joint task per trial whose frames are flatfield-corrected
    (:func:`tracks_jointly`) and one task per bone of any other trial (one sequential task of its
    bones with ``subtract=True``, the ``sequential_subtract`` the tasks will run with), ``"joint"``
    one joint task per trial, ``"sequential"`` one sequential task per trial (its bones one after
    another, the others subtracted), or one task per (trial, bone) with ``split_bones``.
    ``joint=True`` (``False``) is ``mode="joint"`` (``"sequential"``). With ``ranges``, one task
    per frame range between the bone's (the group's common) hand-set keyframes in ``frames``
    (``[start, stop)``, default all; :func:`keyframe_ranges`).

    Raises
    ------
    StudyError
        A folder that is not a study. (With ``mode="auto"`` a trial whose saved correction
        cannot be read gets one joint task, which fails when it runs, naming the file; the
        other trials' tasks are made as usual.)
    ValueError
        An unknown ``mode``, or one ``joint`` contradicts; ``split_bones`` with a mode other
        than ``"sequential"``; a trial or bone named in ``trials``/``bones`` that none of the
        studies has, or no task.
    """
    from ..study import Study, StudyError

    if mode not in MODES:
        raise ValueError(f"mode: expected one of {list(MODES)}, got {mode!r}")
    if joint is not None:
        wanted = "joint" if joint else "sequential"
        if mode not in ("auto", wanted):
            raise ValueError(f"joint: joint={joint} contradicts mode={mode!r}")
        mode = wanted
    if split_bones and mode != "sequential":
        raise ValueError(f"split_bones: one task per bone is a choice of mode 'sequential', not {mode!r}")
    tasks: list[BatchTask] = []
    seen_trials: set[str] = set()
    seen_bones: set[str] = set()
    for folder in studies:
        with Study.open(folder, mode="r", check_files=False) as st:
            corrected: dict[str, bool] = {}  # by calibration: the trials of one share its correction
            for t in st.trials:
                if trials is not None and t not in trials:
                    continue
                seen_trials.add(t)
                names = [b for b in st.trial(t).bones if bones is None or b in bones]
                seen_bones.update(names)
                if not names:
                    continue
                together = mode == "joint"
                sequential = mode == "sequential" and not split_bones and len(names) > 1
                if mode == "auto" and len(names) > 1:
                    cal = st.manifest["trials"][t]["calibration"]
                    if cal not in corrected:
                        try:
                            corrected[cal] = tracks_jointly(st, t)
                        except StudyError:  # its task fails when it runs, saying why; the others run
                            corrected[cal] = True
                    together = corrected[cal]
                    sequential = not together and subtract is True  # as talus track --sequential-subtract on
                how = "sequential" if sequential else None
                groups = [tuple(names)] if together or sequential else [(b,) for b in names]
                if not ranges:
                    tasks += [BatchTask(str(st.folder), t, g, mode=how) for g in groups]
                    continue
                trial = st.trial(t)
                lo, hi = frames if frames is not None else (0, trial.n_frames)
                hi = min(int(hi), trial.n_frames)
                if not 0 <= lo < hi:
                    raise ValueError(f"frames: {lo}:{hi} is not a range of trial {t!r} (0:{trial.n_frames})")
                keys = {b: set(trial.results(b).keyframes) for b in names}
                for g in groups:
                    common = set.intersection(*(keys[b] for b in g))
                    tasks += [BatchTask(str(st.folder), t, g, r, mode=how)
                              for r in keyframe_ranges(common, lo, hi)]
    for what, asked, seen in (("--trials", trials, seen_trials), ("--bones", bones, seen_bones)):
        missing = [x for x in (asked or ()) if x not in seen]
        if missing:
            raise ValueError(f"{what}: {missing} not found in the studies {[str(s) for s in studies]}")
    if not tasks:
        raise ValueError(f"studies: no (trial, bone) to track in {[str(s) for s in studies]}")
    return tasks


def _emit(event: dict) -> None:
    """Send ``event`` to the batch's client when running on a Dask worker (else nothing)."""
    try:
        from distributed import get_worker

        worker = get_worker()
    except (ImportError, ValueError):
        return
    worker.log_event(EVENT_TOPIC, event)


def run_task(task: BatchTask, settings: TaskSettings | None = None, *,
             progress: Callable[[dict], None] | None = None,
             cancel: Callable[[], bool] | None = None, stop_event: str | None = None) -> dict:
    """Track ``task`` into its study's journal (resuming what is there) and return its record:
    ``key``, ``status`` (``"complete"``, ``"stopped"`` — nothing could be tracked, the reason in
    ``stopped`` — or ``"cancelled"``), frame counts, ``mode`` and ``sequential_subtract`` (with
    ``sequential_subtract_note``; the module notes), ``seconds`` (wall), ``load_s`` (opening the
    study, reading the bones' CTs, opening the views, reading the journals), ``first_frame_s``
    (after loading, until the first frame is registered: bone models, renderer and Warp kernels,
    and the first frame's widened search and its check), ``frame_s`` (median of the later
    frames), host and process. ``progress(event)`` (and, on a Dask worker, the client) gets an
    event per frame (its end event carries ``mode``, ``sequential_subtract``, ``joint_rounds`` and
    ``joint_restart``, with their notes). ``cancel()``
    (or, on a Dask worker, the Dask event named ``stop_event``) stops the task between
    registrations: the frames done stay in the journal."""
    from ..study import Study
    from .batch_journal import BATCH_TASK, SharedJournals
    from .from_study import track_study
    from .trial import journal_inputs

    settings = settings or TaskSettings()
    t0 = time.perf_counter()
    device = settings.device  # None: CUDA when this process sees a GPU (a CPU worker sees none)
    marks: list[float] = []
    base = {"key": task.key, "host": socket.gethostname(), "pid": os.getpid()}
    stop = cancel or stop_flag(stop_event)
    if task.frames is not None and settings.guess == "spline":
        raise ValueError("guess: a frame-range task cannot use the spline guess (its knots would be "
                         "other ranges' results); use 'velocity' or 'previous'")

    resumed: set[tuple[str, int]] = set()  # (bone, frame) done before, from the journal

    def on_frame(done, total, fr):
        again = (fr.bone, int(fr.frame)) in resumed
        if not again:
            marks.append(time.perf_counter())
        event = dict(base, kind="frame", done=int(done), total=int(total), bone=fr.bone,
                     frame=int(fr.frame), score=None if fr.score is None else float(fr.score),
                     resumed=again)
        _emit(event)
        if progress is not None:
            progress(event)

    start = dict(base, kind="start", device=device or "default")
    _emit(start)
    if progress is not None:
        progress(start)
    with Study.open(task.study, mode="w", check_files=False) as st:
        trial = st.trial(task.trial)
        for b in task.bones:
            st.bone_volume(b)  # read once here (cached for track_study) to time the loading
        frames = task.order
        if frames is None and settings.frames is not None:
            frames = list(range(*settings.frames))
        order = list(range(trial.n_frames)) if frames is None else frames
        _, skip = journal_inputs({b: trial.results(b) for b in task.bones}, order, resume=True)
        resumed.update((b, int(f)) for b in task.bones for f in skip[b])
        load_s = time.perf_counter() - t0
        result, report = track_study(
            st if task.frames is None else SharedJournals(st), task.trial, list(task.bones), frames,
            options=settings.tracking_options(joint=task.tracking_mode == "joint"), device=device,
            resume=True, threshold_hu=settings.threshold_hu, progress=on_frame,
            report_name=task.report_name, cancel=stop, lock_by=BATCH_TASK)
        n_frames = len(order)
    seconds = time.perf_counter() - t0
    summary = dict(report.get("summary") or {})
    used = report.get("options") or {}
    steps = [b - a for a, b in itertools.pairwise(marks)]
    frame_s = sorted(steps)[len(steps) // 2] if steps else None
    record = dict(
        base, study=task.study, trial=task.trial, bones=list(task.bones), device=device or "default",
        status="stopped" if result is None else result.status,
        frames_total=n_frames * len(task.bones),
        frames_tracked=len(marks),  # registered in this run (not those resumed from the journal)
        frames_resumed=len(resumed),
        mode=used.get("mode"),  # as track_study tracked: joint or sequential
        # a sequential task's searches: the neighbours subtracted or not (auto resolved; resume keeps
        # the choice its report recorded), and why where it is not the plain choice; None: joint
        sequential_subtract=used.get("sequential_subtract"),
        sequential_subtract_note=used.get("sequential_subtract_note"),
        # a joint task's rounds per frame (TrackingOptions.joint_rounds), those after the first from the
        # prediction (joint_restart), and the note of a task run again with other ones; None: sequential
        joint_rounds=used.get("joint_rounds"),
        joint_restart=used.get("joint_restart"),
        joint_restart_note=used.get("joint_restart_note"),
        frames_recorded=int(summary.get("recorded", 0)),
        flagged=int(summary.get("flagged", 0)),
        seconds=seconds,
        load_s=load_s,
        first_frame_s=(marks[0] - t0 - load_s) if marks else None,
        frame_s=frame_s,
        stopped=report.get("stopped") or {},
    )
    end = dict(base, kind="end", status=record["status"], seconds=seconds, mode=record["mode"],
               sequential_subtract=record["sequential_subtract"],
               sequential_subtract_note=record["sequential_subtract_note"],
               joint_rounds=record["joint_rounds"], joint_restart=record["joint_restart"],
               joint_restart_note=record["joint_restart_note"])
    _emit(end)
    if progress is not None:
        progress(end)
    return record


def run_serial(tasks: Sequence[BatchTask], settings: TaskSettings | None = None, *,
               progress: Callable[[dict], None] | None = None,
               cancel: Callable[[], bool] | None = None) -> dict:
    """Run ``tasks`` one after the other in this process (no Dask): the reference a batch is
    checked against, and ``talus batch --workers 0``. Returns :func:`summarize`'s summary;
    after ``cancel()`` the task in flight stops and the others are reported cancelled."""
    settings = settings or TaskSettings()
    t0 = time.perf_counter()
    records, failures = [], []
    for task in tasks:
        if cancel is not None and cancel():
            records.append(_cancelled(task))
            continue
        try:
            records.append(run_task(task, settings, progress=progress, cancel=cancel))
        except Exception as exc:  # reported in the summary, the batch goes on
            failures.append({"key": task.key, "error": f"{type(exc).__name__}: {exc}", "attempts": 1})
    passes = trajectory_pass(tasks, records, settings)
    records = final_records(records, passes)  # range tasks' flagged counts after the pass
    summary = summarize(tasks, records, failures, wall_s=time.perf_counter() - t0, workers=0)
    return dict(summary, trajectory_pass=passes)


def trajectory_pass(tasks: Sequence[BatchTask], records: Sequence[dict],
                    settings: TaskSettings | None = None) -> list[dict]:
    """The trajectory check (:func:`core.tracking.flags_post.apply_trajectory_flags`) over the
    frame ranges of each (study, trial, bones) once all of its range tasks are complete
    (``records``: the tasks' records): the ranges' frames judged together from the journal, the
    journal's other good poses as neighbours, the frames whose flag changed journaled again and
    the group's range reports rewritten with the flags as the pass left them
    (:mod:`core.tracking.batch_pass`). Returns one entry per group — ``key``, ``ranges`` (task
    keys), ``judged`` (bone-frames), ``flagged`` (off the trajectory), ``review_flagged`` (bone ->
    frames with any review flag), ``changed`` ([bone, frame]) and ``changes`` (with the flags
    after the pass), ``tasks_flagged`` (task key -> its frames flagged, as its rewritten report
    counts them: frames flagged without a pose, which no journal holds, included), ``reports``
    (rewritten; ``reports_unreadable`` and ``reports_unwritten`` name those it could not read or
    write, with the error: the journal holds the flags after the pass all the same),
    ``seconds``; or ``skipped`` (a range not complete) or ``error`` (e.g. another writer holds the
    bone), the ranges' own flags then staying but in the frames named under ``journaled`` (those
    journaled before it failed, of ``changed_total``) — the batch summary's ``"trajectory_pass"``.
    ``shared_keyframes``: the keyframes two ranges share given both ranges' backward checks, also
    where the group is not judged (``skipped``, ``off``; ``shared_error`` where that failed);
    ``journaled_again``: every frame the pass journaled (:mod:`core.tracking.batch_pass`)."""
    from .batch_pass import run_pass

    return run_pass(tasks, records, settings or TaskSettings())


def _cancelled(task: BatchTask) -> dict:
    """The record of a task cancelled before it started."""
    return dict(key=task.key, study=task.study, trial=task.trial, bones=list(task.bones),
                status="cancelled", frames_tracked=0, frames_recorded=0, seconds=0.0)


def summarize(tasks: Sequence[BatchTask], records: Sequence[dict], failures: Sequence[dict], *,
              wall_s: float, workers: int, attempts: dict[str, int] | None = None,
              dashboard: str | None = None, scheduler: str | None = None,
              startup_s: float | None = None) -> dict:
    """The batch's JSON summary: ``status`` (``"complete"``, or ``"failed"`` when a task failed
    twice, ``"stopped"`` when a task could track nothing), counts, times and every task's record
    (failed tasks with their error)."""
    by_key = {r["key"]: r for r in records}
    failed = {f["key"]: f for f in failures}
    rows = []
    for t in tasks:
        rec = dict(by_key.get(t.key) or dict(key=t.key, study=t.study, trial=t.trial,
                                                bones=list(t.bones), status="failed",
                                                error=failed.get(t.key, {}).get("error")))
        rec["attempts"] = (attempts or {}).get(t.key, failed.get(t.key, {}).get("attempts", 1))
        rows.append(rec)
    statuses = [r["status"] for r in rows]
    status = ("failed" if "failed" in statuses else
              "cancelled" if "cancelled" in statuses else
              "stopped" if "stopped" in statuses else "complete")
    done = [r for r in rows if r["status"] != "failed"]
    busy = sum(r.get("seconds", 0.0) for r in done)
    tracked = sum(r.get("frames_tracked", 0) for r in done)
    return {
        "status": status,
        "tasks": len(rows),
        "tasks_complete": statuses.count("complete"),
        "tasks_failed": statuses.count("failed"),
        "workers": workers,
        "scheduler": scheduler,
        "dashboard": dashboard,
        "wall_s": wall_s,
        "startup_s": startup_s,
        "frames_tracked": tracked,
        "frames_recorded": sum(r.get("frames_recorded", 0) for r in done),
        "task_seconds": busy,
        "frames_per_s": tracked / wall_s if wall_s > 0 else None,
        "failures": [{"key": r["key"], "error": r.get("error"), "attempts": r["attempts"]}
                     for r in rows if r["status"] == "failed"],
        "task_records": rows,
    }


def stop_flag(name: str | None, every_s: float = 0.5) -> Callable[[], bool] | None:
    """A cancel callable that reads the Dask event ``name`` (set by the client to stop the batch)
    at most every ``every_s`` seconds; None without a name or off a Dask worker."""
    if name is None:
        return None
    try:
        from distributed import Event, get_worker

        get_worker()
    except (ImportError, ValueError):
        return None
    event = Event(name)
    state = {"next": 0.0, "set": False}

    def stop() -> bool:
        now = time.monotonic()
        if not state["set"] and now >= state["next"]:
            state["next"] = now + every_s
            try:
                state["set"] = bool(event.is_set())
            except Exception:  # the scheduler is gone: the batch is over
                state["set"] = True
        return state["set"]

    return stop


def __getattr__(name: str):
    """:func:`local_cluster` and :func:`run_batch` live in :mod:`core.tracking.batch_dask` (imported
    by name, so that module's import of this one is no import circle)."""
    if name in ("local_cluster", "run_batch"):
        import importlib

        return getattr(importlib.import_module(f"{__package__}.batch_dask"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
