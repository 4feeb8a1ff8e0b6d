"""``talus batch`` on Dask distributed: the local cluster and the client side of a batch
(:mod:`core.tracking.batch` re-exports :func:`local_cluster` and :func:`run_batch`).

``dask[distributed]`` is the optional ``batch`` extra, imported only inside these functions.
"""

from __future__ import annotations

import contextlib
import os
import time
from collections.abc import Callable, Sequence

from .batch import EVENT_TOPIC, BatchTask, TaskSettings, _cancelled, run_task, stop_flag, summarize

__all__ = ["gpu_count", "local_cluster", "run_batch", "stop_flag"]


def gpu_count() -> int:
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

    gpus = 0 if (device or "").startswith("cpu") else gpu_count()
    if gpus:
        n = min(workers or gpus, gpus)
        specs = {f"gpu{i}": {"cls": Nanny, "options": {
            "nthreads": 1, "resources": {"GPU": 1}, "env": {"CUDA_VISIBLE_DEVICES": str(i)}}}
            for i in range(n)}
    else:
        n = max(1, int(workers or os.cpu_count() or 1))
        threads = max(1, (os.cpu_count() or 1) // n)  # cores per worker (numpy, OpenCV, Warp's DRRs)
        env = {"CUDA_VISIBLE_DEVICES": "", "OMP_NUM_THREADS": str(threads),
               "OPENBLAS_NUM_THREADS": str(threads), "MKL_NUM_THREADS": str(threads),
               "TALUS_CPU_THREADS": str(threads)}
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
              on_start: Callable[[dict], None] | None = None,
              cancel: Callable[[], bool] | None = None, cancel_wait_s: float = 60.0) -> dict:
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
    cancel : callable() -> bool, optional
        Polled about 4 times a second. Once it returns True the tasks not started are cancelled
        and the running ones stop at their next registration (a Dask event they poll), keeping
        the frames done in the journals; they are waited for up to ``cancel_wait_s`` seconds
        (then the local cluster is closed, which ends them). Their records say ``"cancelled"``.
    """
    import dask

    # a local worker whose process died is restarted by its nanny; the cluster waits this long
    # for it to register again before it gives the worker up (Dask's default, 15 s, is shorter
    # than a worker's start on a loaded machine: the retried task then failed as well)
    with dask.config.set({"distributed.deploy.lost-worker-timeout": "300s"}):
        return _run_batch(tasks, settings or TaskSettings(), workers, scheduler, on_event, on_start,
                          cancel, cancel_wait_s)


def _run_batch(tasks, settings, workers, scheduler, on_event, on_start, cancel, cancel_wait_s) -> dict:
    import uuid

    from distributed import Client, Event

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
        stop_name = f"talus-batch-stop-{uuid.uuid4().hex}"
        stop = Event(stop_name, client=client)
        resources = {"GPU": 1} if uses_gpu else None
        futures = {client.submit(run_task, t, settings, key=f"talus-batch-{i}-{t.key}", retries=1,
                                 pure=False, resources=resources, stop_event=stop_name): t
                   for i, t in enumerate(tasks)}
        records, failures = [], []
        pending, stopping = set(futures), None
        while pending:
            done = {f for f in pending if f.done()}
            if not done:
                time.sleep(0.25)
            pending -= done
            for fut in done:
                task = futures[fut]
                if fut.status == "cancelled":
                    records.append(_cancelled(task))
                    continue
                try:
                    records.append(fut.result())
                except Exception as exc:  # a task that failed twice is reported
                    failures.append({"key": task.key, "error": f"{type(exc).__name__}: {exc}",
                                     "attempts": max(2, attempts.get(task.key, 0))})
            if stopping is None and cancel is not None and cancel():
                stopping = time.monotonic() + cancel_wait_s
                stop.set()  # running tasks stop at their next registration
                queued = [f for f in pending if futures[f].key not in attempts]
                client.cancel(queued)
            elif stopping is not None and time.monotonic() >= stopping:
                records += [_cancelled(futures[f]) for f in pending]  # still running: given up
                client.cancel(list(pending))
                pending = set()
        time.sleep(0.2)  # let the last events arrive
        client.unsubscribe_topic(EVENT_TOPIC)
        with contextlib.suppress(Exception):  # an existing scheduler keeps no stale stop event
            stop.clear()
        from .batch import trajectory_pass
        from .batch_pass import final_records

        passes = trajectory_pass(tasks, records, settings)  # ranges' flags judged together
        records = final_records(records, passes)  # range tasks' flagged counts after the pass
        summary = summarize(tasks, records, failures, wall_s=time.perf_counter() - t0,
                            workers=n_workers, attempts=attempts, dashboard=info["dashboard"],
                            scheduler=None if cluster is not None else scheduler, startup_s=startup_s)
        return dict(summary, trajectory_pass=passes)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
