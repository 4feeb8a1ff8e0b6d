"""The run's objects of before it frozen out of the cyclic garbage collector (core.tracking.trial.GC_FREEZE,
core.tracking.gc_pause): the same poses, scores, flags and confidences to the bit as with it off, with a full
collection forced after every frame; the freeze lifted after the run, and left alone where something else
froze objects first."""

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


def test_gc_freeze_gives_the_same_results(walking_talus_64, monkeypatch):
    import core.tracking.trial as trial

    assert trial.GC_FREEZE  # (the default)
    off_seen, on_seen = [], []
    monkeypatch.setattr(trial, "GC_FREEZE", False)
    off = _track(walking_talus_64, off_seen)
    monkeypatch.setattr(trial, "GC_FREEZE", True)
    on = _track(walking_talus_64, on_seen)
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
