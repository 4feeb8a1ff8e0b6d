"""Tracking many trials of many studies as independent tasks, on Dask distributed (``talus batch``).

A *task* is one trial's bone — or one trial's joint bone group (``joint=True``, tracked with
``mode="joint"``) — of one study (:class:`BatchTask`, from :func:`build_tasks`). A task runs
:func:`run_task`: it opens its study for writing, which locks only the journals of its bones
(:meth:`core.study.Study.lock_journal`), and calls :func:`core.tracking.from_study.track_study`
— what ``talus track`` calls — with ``resume=True``, so every registered frame is in the
study's journal as soon as it finishes and a task that runs again (after its worker was killed,
or in a later batch) carries on from the journal: nothing is lost but the frame in flight, and
the poses are those of an uninterrupted run (each registration is seeded from its frame number).
Each task writes its own tracking report, ``results/reports/tracking/<trial>.<bone>.json``.

:func:`run_batch` submits the tasks to a Dask cluster — a local one by default
(:func:`local_cluster`: one worker process per GPU, its ``CUDA_VISIBLE_DEVICES`` set to that GPU
and a ``GPU`` worker resource, or one single-threaded worker process per CPU core group without a
GPU), or an existing scheduler — retries a failed task once (an exception, or its worker dying:
Dask's ``allowed-failures`` is set to 1 for the local cluster), follows the tasks' frames through
worker events, and returns a JSON-ready summary (:func:`summarize`). Nothing here imports Qt;
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

__all__ = [
    "EVENT_TOPIC",
    "BatchTask",
    "TaskSettings",
    "build_tasks",
    "local_cluster",
    "run_batch",
    "run_serial",
    "run_task",
    "summarize",
]

EVENT_TOPIC = "talus-batch"  # worker events: task start, frame done, task end


@dataclass(frozen=True)
class BatchTask:
    """One unit of work: ``bones`` of ``trial`` in the study at ``study`` (an absolute folder).

    More than one bone is a joint bone group (tracked together with ``mode="joint"``)."""

    study: str
    trial: str
    bones: tuple[str, ...]

    @property
    def key(self) -> str:
        """``<study folder name>/<trial>/<bone>[+<bone>...]``: unique within a batch."""
        return f"{Path(self.study).name}/{self.trial}/{'+'.join(self.bones)}"

    @property
    def report_name(self) -> str:
        """The task's tracking report (``results/reports/tracking/<report_name>.json``)."""
        return f"{self.trial}.{'+'.join(self.bones)}" if len(self.bones) > 1 else \
            f"{self.trial}.{self.bones[0]}"


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
        """The :class:`~core.tracking.trial.TrackingOptions` ``talus track`` builds."""
        from .cost import DEFAULT_TERMS, MetricTerm
        from .register import RegistrationOptions
        from .trial import TrackingOptions

        terms = DEFAULT_TERMS if self.metric == "gc" else (MetricTerm(self.metric),)
        reg = RegistrationOptions(terms=terms, bounds=(5.0, 5.0), sigma=(1.0, 1.0), search="local")
        return TrackingOptions(registration=reg, guess=self.guess, mode="joint" if joint else "sequential",
                               confidence=self.confidence, max_uncertainty=self.max_uncertainty,
                               **dict(self.options))


def build_tasks(studies: Sequence[str | os.PathLike], trials: Sequence[str] | None = None,
                bones: Sequence[str] | None = None, *, joint: bool = False) -> list[BatchTask]:
    """The tasks of ``studies``: every trial (or those named in ``trials``) × every bone of it
    (or those named in ``bones``), one task per (trial, bone), or per trial with ``joint``.

    Raises
    ------
    StudyError
        A folder that is not a study.
    ValueError
        A trial or bone named in ``trials``/``bones`` that none of the studies has, or no task.
    """
    from ..study import Study

    tasks: list[BatchTask] = []
    seen_trials: set[str] = set()
    seen_bones: set[str] = set()
    for folder in studies:
        with Study.open(folder, mode="r", check_files=False) as st:
            for t in st.trials:
                if trials is not None and t not in trials:
                    continue
                seen_trials.add(t)
                names = [b for b in st.trial(t).bones if bones is None or b in bones]
                seen_bones.update(names)
                if not names:
                    continue
                groups = [tuple(names)] if joint else [(b,) for b in names]
                tasks += [BatchTask(str(st.folder), t, g) for g in groups]
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
             progress: Callable[[dict], None] | None = None) -> dict:
    """Track ``task`` into its study's journal (resuming what is there) and return its record:
    ``key``, ``status`` (``"complete"``, ``"stopped"`` — nothing could be tracked, the reason in
    ``stopped`` — or ``"cancelled"``), frame counts, ``seconds`` (wall), ``load_s`` (opening the
    study, reading the bones' CTs, opening the views, reading the journals), ``first_frame_s``
    (after loading, until the first frame is registered: bone models, renderer and Warp kernels,
    and the first frame's widened search and its check), ``frame_s`` (median of the later
    frames), host and process. ``progress(event)`` (and, on a Dask worker, the client) gets an
    event per frame."""
    from ..study import Study
    from .from_study import track_study
    from .trial import journal_inputs

    settings = settings or TaskSettings()
    t0 = time.perf_counter()
    device = settings.device  # None: CUDA when this process sees a GPU (a CPU worker sees none)
    marks: list[float] = []
    base = {"key": task.key, "host": socket.gethostname(), "pid": os.getpid()}

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
        frames = None if settings.frames is None else list(range(*settings.frames))
        order = list(range(trial.n_frames)) if frames is None else frames
        _, skip = journal_inputs({b: trial.results(b) for b in task.bones}, order, resume=True)
        resumed.update((b, int(f)) for b in task.bones for f in skip[b])
        load_s = time.perf_counter() - t0
        result, report = track_study(
            st, task.trial, list(task.bones), frames,
            options=settings.tracking_options(joint=len(task.bones) > 1), device=device,
            resume=True, threshold_hu=settings.threshold_hu, progress=on_frame,
            report_name=task.report_name)
        n_frames = len(frames) if frames is not None else trial.n_frames
    seconds = time.perf_counter() - t0
    summary = dict(report.get("summary") or {})
    steps = [b - a for a, b in itertools.pairwise(marks)]
    frame_s = sorted(steps)[len(steps) // 2] if steps else None
    record = dict(
        base, study=task.study, trial=task.trial, bones=list(task.bones), device=device or "default",
        status="stopped" if result is None else result.status,
        frames_total=n_frames * len(task.bones),
        frames_tracked=len(marks),  # registered in this run (not those resumed from the journal)
        frames_resumed=len(resumed),
        frames_recorded=int(summary.get("recorded", 0)),
        flagged=int(summary.get("flagged", 0)),
        seconds=seconds,
        load_s=load_s,
        first_frame_s=(marks[0] - t0 - load_s) if marks else None,
        frame_s=frame_s,
        stopped=report.get("stopped") or {},
    )
    end = dict(base, kind="end", status=record["status"], seconds=seconds)
    _emit(end)
    if progress is not None:
        progress(end)
    return record


def run_serial(tasks: Sequence[BatchTask], settings: TaskSettings | None = None, *,
               progress: Callable[[dict], None] | None = None) -> dict:
    """Run ``tasks`` one after the other in this process (no Dask): the reference a batch is
    checked against, and ``talus batch --workers 0``. Returns :func:`summarize`'s summary."""
    settings = settings or TaskSettings()
    t0 = time.perf_counter()
    records, failures = [], []
    for task in tasks:
        try:
            records.append(run_task(task, settings, progress=progress))
        except Exception as exc:  # reported in the summary, the batch goes on
            failures.append({"key": task.key, "error": f"{type(exc).__name__}: {exc}", "attempts": 1})
    return summarize(tasks, records, failures, wall_s=time.perf_counter() - t0, workers=0)


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


# ------------------------------------------------------------------------------ Dask
def _gpu_count() -> int:
    """CUDA devices Warp sees here (0 without a GPU or a driver)."""
    try:
        import warp as wp

        wp.config.quiet = True
        wp.init()
        return int(wp.get_cuda_device_count())
    except Exception:  # no driver, no CUDA: CPU workers
        return 0


def local_cluster(workers: int | None = None, *, device: str | None = None,
                  dashboard_address: str | None = ":0"):
    """A Dask cluster on this machine: one worker process per GPU (``CUDA_VISIBLE_DEVICES`` set
    to it, a ``GPU: 1`` resource) or, without a GPU or with ``device="cpu"``, one
    single-threaded worker process per CPU core group (``workers`` of them; default: the CPU
    count). Each worker runs one task at a time; a worker that dies is restarted by its nanny.

    Returns
    -------
    (cluster, n_workers, uses_gpu)
    """
    import dask
    from distributed import Nanny, Scheduler, SpecCluster

    gpus = 0 if (device or "").startswith("cpu") else _gpu_count()
    if gpus:
        n = min(workers or gpus, gpus)
        specs = {f"gpu{i}": {"cls": Nanny, "options": {
            "nthreads": 1, "resources": {"GPU": 1}, "env": {"CUDA_VISIBLE_DEVICES": str(i)}}}
            for i in range(n)}
    else:
        n = max(1, int(workers or os.cpu_count() or 1))
        threads = max(1, (os.cpu_count() or 1) // n)  # cores per worker (numpy, OpenCV)
        env = {"CUDA_VISIBLE_DEVICES": "", "OMP_NUM_THREADS": str(threads),
               "OPENBLAS_NUM_THREADS": str(threads), "MKL_NUM_THREADS": str(threads)}
        specs = {f"cpu{i}": {"cls": Nanny, "options": {"nthreads": 1, "env": env}} for i in range(n)}
    for spec in specs.values():  # the workers' own log lines only for errors (progress is ours)
        spec["options"]["silence_logs"] = 40
    scheduler = {"cls": Scheduler, "options": {"dashboard_address": dashboard_address}}
    with dask.config.set({"distributed.scheduler.allowed-failures": 1,
                          "distributed.worker.daemon": False}):
        cluster = SpecCluster(workers=specs, scheduler=scheduler, silence_logs=40)
    return cluster, n, bool(gpus)


def run_batch(tasks: Sequence[BatchTask], settings: TaskSettings | None = None, *,
              workers: int | None = None, scheduler: str | None = None,
              on_event: Callable[[dict], None] | None = None,
              on_start: Callable[[dict], None] | None = None) -> dict:
    """Run ``tasks`` on Dask and return :func:`summarize`'s summary.

    Parameters
    ----------
    workers : int, optional
        Worker processes of the local cluster (default: one per GPU, else per CPU core).
    scheduler : str, optional
        Address of an existing Dask scheduler (``tcp://host:8786``) instead of a local cluster;
        its workers must reach the study folders at the same paths, and should run one task at a
        time each (``dask worker --nthreads 1``; ``--resources GPU=1`` on GPU nodes).
    on_event : callable(event), optional
        Called on the client for each worker event (``kind``: ``"start"``, ``"frame"``,
        ``"end"``; ``key`` of the task).
    on_start : callable(info), optional
        Called once the cluster is up with ``{"dashboard", "scheduler", "workers"}``.
    """
    from distributed import Client, as_completed

    settings = settings or TaskSettings()
    t0 = time.perf_counter()
    cluster = None
    uses_gpu = False
    if scheduler is None:
        cluster, n_workers, uses_gpu = local_cluster(workers, device=settings.device)
        client = Client(cluster)
    else:
        client = Client(scheduler)
        n_workers = len(client.scheduler_info().get("workers", {}))
    attempts: dict[str, int] = {}
    try:
        client.wait_for_workers(1)
        info = {"dashboard": client.dashboard_link, "scheduler": client.scheduler.address,
                "workers": n_workers}
        if on_start is not None:
            on_start(info)
        startup_s = time.perf_counter() - t0

        def handler(event):
            msg = event[1] if isinstance(event, tuple) and len(event) == 2 else event
            if isinstance(msg, dict):
                if msg.get("kind") == "start":
                    attempts[msg["key"]] = attempts.get(msg["key"], 0) + 1
                if on_event is not None:
                    on_event(msg)

        client.subscribe_topic(EVENT_TOPIC, handler)
        resources = {"GPU": 1} if uses_gpu else None
        futures = {client.submit(run_task, t, settings, key=f"talus-batch-{i}-{t.key}", retries=1,
                                 pure=False, resources=resources): t for i, t in enumerate(tasks)}
        records, failures = [], []
        for fut in as_completed(futures):
            task = futures[fut]
            try:
                records.append(fut.result())
            except Exception as exc:  # a task that failed twice is reported
                failures.append({"key": task.key, "error": f"{type(exc).__name__}: {exc}",
                                 "attempts": max(2, attempts.get(task.key, 0))})
        time.sleep(0.2)  # let the last events arrive
        client.unsubscribe_topic(EVENT_TOPIC)
        return summarize(tasks, records, failures, wall_s=time.perf_counter() - t0,
                         workers=n_workers, attempts=attempts, dashboard=info["dashboard"],
                         scheduler=None if cluster is not None else scheduler, startup_s=startup_s)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()

