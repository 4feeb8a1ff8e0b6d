"""flags_post's kept tables (SHARE_TABLE) are the calling thread's: release_tables() at one run's end lets go
of that thread's only, and the oldest let go past four is that thread's own."""

from __future__ import annotations

import threading
from concurrent.futures import ThreadPoolExecutor

import numpy as np

import core.tracking.flags_post as fp


def _poses(n, shift=0.0):
    P = np.tile(np.eye(4), (n, 1, 1))
    t = np.arange(n, dtype=float)
    P[:, 0, 3] = 0.5 * t + shift
    P[:, 1, 3] = 0.01 * t**2
    return P


_OTHER = ThreadPoolExecutor(1)  # one other thread, the same for every call


def _in_thread(f):
    return _OTHER.submit(f).result()


def test_release_and_eviction_are_per_thread(monkeypatch):
    monkeypatch.setattr(fp, "_TABLES", {})
    fr, c = np.arange(12), np.zeros(3)
    other = {}

    def elsewhere():
        fp.trajectory_residuals(fr, _poses(12, 100.0), c)
        other["tid"] = threading.get_ident()
        return set(fp._TABLES)

    keys = _in_thread(elsewhere)
    assert len(keys) == 1 and next(iter(keys))[0] == other["tid"]
    for k in range(6):  # this thread's: four kept at most, the oldest let go first, the other's kept
        fp.trajectory_residuals(fr, _poses(12, float(k)), c)
    mine = [k for k in fp._TABLES if k[0] == threading.get_ident()]
    assert len(mine) == 4 and keys <= set(fp._TABLES)
    assert mine[0][2] == fp._key(*fp._inputs(fr, _poses(12, 2.0), c)[:4], fp.HALF_WINDOW, fp.DEGREE,
                                 fp.ENDS)[2]
    fp.release_tables()  # (this thread's run ends: the other's pending table stays)
    assert set(fp._TABLES) == keys
    # the other thread's review takes its own table; a review here of the same inputs makes its own
    R = fp.trajectory_residuals(fr, _poses(12, 100.0), c)
    assert len(fp._TABLES) == 2
    got = _in_thread(lambda: fp.trajectory_review(fr, _poses(12, 100.0), c))
    assert set(fp._TABLES) == {k for k in fp._TABLES if k[0] == threading.get_ident()}
    assert got == fp.trajectory_review(fr, _poses(12, 100.0), c) and not fp._TABLES
    assert np.isfinite(R).any()
    fp.trajectory_residuals(fr, _poses(12, 100.0), c)
    _in_thread(fp.release_tables)  # (the other thread's run ends: nothing of this one's let go)
    assert len(fp._TABLES) == 1


def test_tables_of_threads_gone_are_bounded(monkeypatch):
    monkeypatch.setattr(fp, "_TABLES", {})
    fr, c = np.arange(12), np.zeros(3)
    for k in range(20):
        fp._TABLES[(-1 - k, b"")] = None  # (threads gone without release_tables)
    fp.trajectory_residuals(fr, _poses(12), c)
    assert len(fp._TABLES) == 20 and (-1, b"") not in fp._TABLES
