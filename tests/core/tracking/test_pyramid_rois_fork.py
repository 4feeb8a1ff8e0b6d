"""engine_frames.pyramid_rois' threads in a forked process: a child forked after the parent prepared
regions (its thread pool made) prepares its own — the parent's threads are not in the child."""

from __future__ import annotations

import multiprocessing as mp
import warnings

import numpy as np

from tests.core.tracking.test_pyramid_rois_threads import _frame

ROI = np.array([[10, 0, 70, 90], [0, 20, 120, 80]])


def _child(q) -> None:
    from core.tracking.engine_frames import pyramid_rois

    rois, _ = pyramid_rois(_frame(2, 1), [0, 1], ROI, 2.0)
    q.put([float(r.sum()) for r in rois])


def test_a_forked_child_prepares_the_views_side_by_side():
    from core.tracking.engine_frames import pyramid_rois

    want = [float(r.sum()) for r in pyramid_rois(_frame(2, 1), [0, 1], ROI, 2.0)[0]]  # (the pool made)
    ctx = mp.get_context("fork")
    q = ctx.Queue()
    with warnings.catch_warnings():  # (Python warns of a fork with threads running: here none runs)
        warnings.simplefilter("ignore", DeprecationWarning)
        p = ctx.Process(target=_child, args=(q,))
        p.start()
    p.join(60)
    alive = p.is_alive()
    if alive:
        p.kill()
        p.join()
    assert not alive, "the child hung in pyramid_rois"
    assert p.exitcode == 0 and q.get(timeout=5) == want


def test_imports_without_register_at_fork(monkeypatch):
    """Where os has no register_at_fork (Windows), the module imports all the same."""
    import importlib
    import os

    import core.tracking.engine_frames as ef

    monkeypatch.delattr(os, "register_at_fork")
    try:
        importlib.reload(ef)
    finally:
        monkeypatch.undo()
        importlib.reload(ef)
