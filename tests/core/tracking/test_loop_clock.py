"""The frame clock of the speed tools (core.studies.tracking.loop_clock): per frame its wall, registrations,
feed and collections, the slow frames and their runs, and the feed's methods put back after."""

from __future__ import annotations

import numpy as np


def _fr(frame, time_s, evaluations=10, retried=False, flags=(), steps=3):
    from core.tracking.results import FrameResult

    return FrameResult("talus", frame, np.eye(4), 0.9, evaluations, time_s, not flags, tuple(flags), retried,
                       None, {"likelihood_steps": steps, "other_s": 0.001})


def test_rows_slow_frames_and_clusters():
    from core.studies.tracking.loop_clock import FrameClock

    c = FrameClock()
    c.start = (0.0, 0.0, 0.0)
    walls = [0.05, 0.005, 0.005, 0.02, 0.021, 0.005, 0.005, 0.018, 0.005]  # frames 0..8
    t = 0.0
    for f, w in enumerate(walls):
        t += w
        c.results[f] = [_fr(f, w - 0.001, evaluations=100 if w > 0.01 else 10, retried=f == 4)]
        c.ends[f] = (t, t / 2, t)
    c.gets = [(0.05, 0.0502, 1, True)]
    c.gcs = [(0.081, 0.083, 2)]  # inside frame 4 (0.080-0.101)
    c.worker = [(0.049, 0.052)]
    c.stop = (t + 0.01, t / 2 + 0.004, t + 0.01)
    c.after = {"apply_trajectory_flags": (0.003, 0.0025)}
    rows = c.rows(range(9))
    assert [r["frame"] for r in rows] == list(range(9))
    assert abs(rows[1]["ms"] - 5.0) < 1e-9 and abs(rows[1]["reg_ms"] - 4.0) < 1e-9
    assert abs(rows[1]["loop_ms"] - 1.0) < 1e-9 and abs(rows[1]["cpu_ms"] - 2.5) < 1e-9
    assert abs(rows[1]["feed_wait_ms"] - 0.2) < 1e-6 and rows[1]["feed_ready"] is True
    assert abs(rows[1]["worker_ms"] - 2.0) < 1e-6 and abs(rows[0]["worker_ms"] - 1.0) < 1e-6
    assert rows[4]["gc"] == [2] and abs(rows[4]["gc_ms"] - 2.0) < 1e-6 and rows[4]["retried"]
    assert rows[2]["feed_ready"] is None and rows[4]["stage_steps"] == 3
    got = c.report(range(9), 0.0, t + 0.01)
    assert [r["frame"] for r in got["slow"]] == [3, 4, 7]  # over 2x the median (5 ms)
    assert got["clusters"] == [[3, 4], [7, 7]]
    assert [r["frame"] for r in got["slowest_records"]] == [4, 3, 7]
    assert abs(got["typical"]["ms"] - 5.0) < 1e-9 and got["slow"][0]["evaluations"] == 100
    assert abs(got["after_last"]["ms"] - 10.0) < 1e-6 and abs(got["after_last"]["cpu_ms"] - 4.0) < 1e-6
    assert abs(got["after_last"]["post_pass_ms"] - 3.0) < 1e-9 and "backward_ms" not in got["after_last"]
    assert abs(got["after_last_frame_ms"] - 10.0) < 1e-6 and got["slowest"][0][0] == 4


def test_watching_times_the_feed_and_puts_it_back():
    import gc

    import core.tracking.backward_check as backward
    import core.tracking.feed as feed
    import core.tracking.trial as trial
    from core.studies.tracking.loop_clock import FrameClock
    from core.tracking.options import TrackingOptions

    before = (feed.FrameFeed.get, feed.FrameFeed._prepare, backward.backward_check,
              trial.apply_trajectory_flags)
    o = TrackingOptions()
    imgs = {f: [np.full((32, 32), 0.5 + 0.01 * f), np.full((32, 32), 0.4)] for f in range(3)}
    c = FrameClock()
    with c.watching():
        fd = feed.FrameFeed(imgs.__getitem__, o.valid_range, o.erode_px)
        try:
            for f in range(3):
                fd.get(f)
                if f + 1 < 3:
                    fd.prefetch(f + 1)
                c.progress(f + 1, 3, _fr(f, 0.0))
                gc.collect()
        finally:
            fd.close()
        assert trial.apply_trajectory_flags is not before[3]  # (timed within the block)
    assert (feed.FrameFeed.get, feed.FrameFeed._prepare, backward.backward_check,
            trial.apply_trajectory_flags) == before
    assert [g[2] for g in c.gets] == [0, 1, 2] and len(c.worker) == 3 and len(c.gcs) >= 3
    assert c._gc not in gc.callbacks and c.stop is not None
    rows = c.rows(range(3))
    assert 2 in rows[1]["gc"] and rows[1]["feed_ready"] in (True, False)
