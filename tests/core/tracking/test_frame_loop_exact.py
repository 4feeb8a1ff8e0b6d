"""The frame loop's host work trimmed exactly, against the loop without the trims (the talus tracked 8 frames
in ideal 64² views with the likelihood stage, Warp's CPU device): the same poses, scores, flags and
confidences to the bit.

* The run's objects of before it frozen out of the cyclic garbage collector (core.tracking.trial.GC_FREEZE,
  core.tracking.gc_pause), with a full collection forced after every frame; the freeze lifted after the
  run, and left alone where something else froze objects first.
* The constant-velocity predictions kept by their inputs (core.tracking.checks._predict: a frame's motion
  prediction is the next frame's newest motion miss), against a run that keeps none.
* The backward check's frame read, prepared and put on the device while the last frame registers
  (core.tracking.trial.BACKWARD_AHEAD; engine_upload.DEVICES patched to take the CPU, in both runs) and its
  trajectory scales computed during its registration's final stage (core.tracking.backward_check.
  SCALE_AHEAD).
* The trajectory post-pass taking the table of local fits the backward check's scales made
  (core.tracking.flags_post.SHARE_TABLE), its residuals kept by their neighbours
  (core.tracking.flags_fit.MEMO) and its deltas made in one batch (core.tracking.flags_fit.BATCHED)."""

from __future__ import annotations

import gc

from tests.core.tracking.test_joint_pipeline import _same

FRAMES = range(0, 8)


def _track(walk, seen):
    from core.tracking.register import RegistrationOptions
    from core.tracking.trial import TrackingOptions, track

    sc, model = walk["scene"], walk["model"]
    keys = {model.name: {FRAMES[0]: sc.poses(FRAMES[0])[0]}}
    ro = RegistrationOptions(bounds=(5.0, 5.0), sigma=(1.0, 1.0), search="newton")
    o = TrackingOptions(verify_restarts=0, refine_likelihood=True, registration=ro)

    def progress(done, total, fr):
        seen.append(gc.get_freeze_count())
        gc.collect()  # a full collection after every frame: whatever the collector does, the same results

    return track(walk["renderer"], [model], walk["frames"], list(FRAMES), keyframes=keys, options=o,
                 progress=progress)


class _NoCache(dict):
    """A cache that keeps nothing."""

    def get(self, key, default=None):
        return default

    def __setitem__(self, key, value) -> None:
        pass


def test_trimmed_loop_gives_the_same_results(walking_talus_64, monkeypatch):
    import inspect

    import core.tracking.backward_check as backward
    import core.tracking.checks as checks
    import core.tracking.engine_upload as eu
    import core.tracking.feed as feed
    import core.tracking.flags_fit as ff
    import core.tracking.flags_post as fp
    import core.tracking.trial as trial

    assert not trial.GC_FREEZE and trial.BACKWARD_AHEAD and backward.SCALE_AHEAD  # (the defaults)
    assert fp.SHARE_TABLE and ff.MEMO and ff.BATCHED
    monkeypatch.setattr(eu, "DEVICES", ("cuda", "cpu"))  # (the shared upload and the uploads ahead on CPU)
    got, ahead, scaled = [], [], []
    real_get, real_ahead, real_scale = feed.FrameFeed.get, feed.FrameFeed.upload_ahead, backward._scale

    def get(self, f):
        got.append((f, self.ahead is not None and self.ahead[0] == f))  # (taken from the look-ahead)
        return real_get(self, f)

    def upload_ahead(self, device):
        if self.ahead is not None:  # (the worker's preparation finished first: on a loaded machine it may
            self.ahead[2].exception()  # not be by the last frame's stage, and the upload then waits a frame)
        ok = real_ahead(self, device)
        ahead.append((self.ahead[0] if self.ahead else None, ok))
        return ok

    def scale(*a, **k):
        scaled.append(any(fr.function == "final_stage_idle" for fr in inspect.stack()))  # (in the stage)
        return real_scale(*a, **k)

    monkeypatch.setattr(feed.FrameFeed, "get", get)
    monkeypatch.setattr(feed.FrameFeed, "upload_ahead", upload_ahead)
    monkeypatch.setattr(backward, "_scale", scale)
    off_seen, on_seen = [], []
    switches = ((trial, "GC_FREEZE"), (trial, "BACKWARD_AHEAD"), (backward, "SCALE_AHEAD"),
                (fp, "SHARE_TABLE"), (ff, "MEMO"), (ff, "BATCHED"))
    for m, v in switches:
        monkeypatch.setattr(m, v, False)
    monkeypatch.setattr(checks, "_PREDICTIONS", _NoCache())
    monkeypatch.setattr(eu, "_UPLOADS", {})
    monkeypatch.setattr(eu, "_ACTIVE", {})
    off = _track(walking_talus_64, off_seen)
    assert got[-1] == (FRAMES[0], False) and scaled == [False]  # (as before: read after the loop)
    got.clear(), ahead.clear(), scaled.clear()
    for m, v in switches:
        monkeypatch.setattr(m, v, True)
    tables = {}
    monkeypatch.setattr(fp, "_TABLES", tables)
    real_table, made = fp._Table, []

    def table(*a, **k):
        made.append(1)
        return real_table(*a, **k)

    monkeypatch.setattr(fp, "_Table", table)
    kept = {}
    monkeypatch.setattr(checks, "_PREDICTIONS", kept)
    monkeypatch.setattr(eu, "_UPLOADS", {})
    monkeypatch.setattr(eu, "_ACTIVE", {})
    on = _track(walking_talus_64, on_seen)
    assert kept  # (the predictions were kept)
    assert got[-1] == (FRAMES[0], True)  # the backward check's frame taken from the look-ahead
    assert (FRAMES[0], True) in ahead  # and put on the device during the last frame's stage
    assert scaled == [True]  # the scale computed during the backward registration's stage
    assert len(made) == 1 and not tables  # its table taken by the post-pass
    _same(off, on)
    assert off.status == on.status == "complete"
    assert not any(off_seen) and all(on_seen) and len(on_seen) == len(FRAMES)  # frozen while it ran
    assert gc.get_freeze_count() == 0  # and lifted after


def test_frozen_leaves_an_earlier_freeze_alone():
    from core.tracking.gc_pause import GcWatch, frozen

    with frozen(True):
        assert gc.get_freeze_count() > 0
    assert gc.get_freeze_count() == 0
    with frozen(False):
        assert gc.get_freeze_count() == 0
    gc.freeze()
    try:
        n = gc.get_freeze_count()
        with frozen(True):
            pass
        assert gc.get_freeze_count() == n  # not unfrozen by the block
    finally:
        gc.unfreeze()
    with GcWatch() as w:
        gc.collect()
    assert w.collections[2] >= 1 and w.pause_s[2] >= 0.0
    assert w._cb not in gc.callbacks
    assert set(w.to_dict()) == {"collections", "pause_ms", "pause_ms_total"}


def test_kept_prediction_same_bits_new_array():
    import numpy as np

    import core.tracking.checks as checks
    from core.geometry.transforms import pose_from_params

    c = np.array([10.0, -20.0, 35.0])
    T0 = pose_from_params(np.r_[1.0, 2.0, -0.5, 0.01, -0.02, 0.03], center=c)
    T1 = pose_from_params(np.r_[1.4, 2.3, -0.2, 0.015, -0.018, 0.034], center=c)
    checks._PREDICTIONS.clear()
    a = checks._predict(3, T0, 5, T1, 6, c)
    b = checks._predict(3, T0.copy(), 5, T1.copy(), 6, c.copy())
    assert a is not b and a.tobytes() == b.tobytes()
    a[0, 0] = 7.0  # the caller's own array: the kept one unchanged
    assert checks._predict(3, T0, 5, T1, 6, c).tobytes() == b.tobytes()
    assert checks._predict(3, T0, 5, T1, 7, c).tobytes() != b.tobytes()  # another frame


def test_switch_interval_set_within_and_put_back():
    import sys

    from core.tracking.trial import SWITCH_INTERVAL, _switch_interval

    assert SWITCH_INTERVAL is None  # (the default: left as it is)
    was = sys.getswitchinterval()
    with _switch_interval(None):
        assert sys.getswitchinterval() == was
    with _switch_interval(0.0005):
        assert abs(sys.getswitchinterval() - 0.0005) < 1e-9
    assert sys.getswitchinterval() == was
    a, b = _switch_interval(0.0005), _switch_interval(0.0005)  # two runs overlapping (threads)
    a.__enter__()
    b.__enter__()
    a.__exit__(None, None, None)  # the first to leave: the other still runs
    assert abs(sys.getswitchinterval() - 0.0005) < 1e-9
    b.__exit__(None, None, None)
    assert sys.getswitchinterval() == was  # the last puts back what the first found


def test_host_pauses_gil_overshoot_puts_the_interval_back():
    import sys

    from core.studies.tracking.host_pauses import gil_overshoot

    was = sys.getswitchinterval()
    got = gil_overshoot(n=10, worker=True, interval=0.0005)
    assert sys.getswitchinterval() == was
    assert got["worker"] and got["switch_interval_s"] == 0.0005 and got["sum_ms"] >= 0.0
    assert gil_overshoot(n=5)["frames_prepared"] == 0
