"""Sequential tracking's search with the neighbours subtracted
(TrackingOptions.sequential_subtract, core.tracking.frame_step): each bone is searched with the bones
registered earlier in the frame subtracted at their registered poses and the others at their
guesses; off, each bone is searched against the whole image; joint tracking is the same either way
(ideal 128² views of the talus and calcaneus, Warp's CPU device)."""

from __future__ import annotations

import numpy as np


def _run(scene, monkeypatch, *, mode: str, subtract: bool | None, skip: bool = True):
    """Track frames 0-1 from keyframes at frame 0 (``skip``: frame 0 taken as registered, not searched),
    every registration's bone, subtracted neighbours and result recorded."""
    import core.tracking.frame_step as fs
    from core.tracking.register import RegistrationOptions
    from core.tracking.trial import TrackingOptions, track

    sc, models, r, frames = scene
    seen = []
    real = fs.register_checked

    def spy(*a, **k):
        got = real(*a, **k)
        others = a[9]
        seen.append((a[3], None if others is None else (np.array(others[0]), list(others[1])), got))
        return got

    monkeypatch.setattr(fs, "register_checked", spy)
    keyframes = {m.name: {0: sc.poses(0)[k]} for k, m in enumerate(models)}
    reg = RegistrationOptions(bounds=(5.0, 5.0), sigma=(1.0, 1.0), search="newton")
    o = TrackingOptions(mode=mode, verify_restarts=0, registration=reg, trajectory_limit=None,
                        sequential_subtract=subtract)
    res = track(r, models, frames.__getitem__, [0, 1], keyframes=keyframes, skip=keyframes if skip else None,
                options=o)
    return res, seen


def test_sequential_search_alone_by_default(talus_calcaneus_128, monkeypatch):
    _, seen = _run(talus_calcaneus_128, monkeypatch, mode="sequential", subtract=False)
    assert [s[0] for s in seen] == [0, 1]
    assert all(s[1] is None for s in seen)


def test_sequential_search_subtracts_registered_and_guessed_neighbours(talus_calcaneus_128, monkeypatch):
    sc = talus_calcaneus_128[0]
    res, seen = _run(talus_calcaneus_128, monkeypatch, mode="sequential", subtract=True)
    (b0, o0, a0), (b1, o1, _) = seen
    assert (b0, b1) == (0, 1)
    # the talus first: the calcaneus at its guess (its only good pose, frame 0's)
    assert o0[1] == [1] and np.array_equal(o0[0][0], sc.poses(0)[1])
    # then the calcaneus: the talus at the pose just registered in this frame
    assert o1[1] == [0] and np.array_equal(o1[0][0], a0.result.pose)
    for k, m in enumerate(talus_calcaneus_128[1]):
        fr = res.results[(m.name, 1)]
        d = fr.pose[:3, 3] - sc.poses(1)[k][:3, 3]
        assert np.linalg.norm(d) < 1.0  # still registered (ideal 128² views, 1.5 mm voxels)


def test_the_option_is_a_bool_or_auto():
    import pytest

    from core.tracking.trial import TrackingOptions

    assert TrackingOptions().sequential_subtract is None  # auto: track_study decides, track() alone: off
    for bad in (1, "on", 0.0):
        with pytest.raises(ValueError, match="sequential_subtract"):
            TrackingOptions(sequential_subtract=bad)


def test_track_alone_keeps_auto_off(talus_calcaneus_128, monkeypatch):
    """track() cannot tell whether the frames are flatfield-corrected: None searches alone."""
    _, seen = _run(talus_calcaneus_128, monkeypatch, mode="sequential", subtract=None)
    assert [s[0] for s in seen] == [0, 1]
    assert all(s[1] is None for s in seen)


def test_joint_tracking_unchanged_by_the_switch(talus_calcaneus_128, monkeypatch):
    off, _ = _run(talus_calcaneus_128, monkeypatch, mode="joint", subtract=False)
    on, _ = _run(talus_calcaneus_128, monkeypatch, mode="joint", subtract=True)
    assert_same_results(off, on)


def assert_same_results(off, on):
    """The two tracking results hold the same frames with bit-equal poses, scores and flags."""
    assert off.results.keys() == on.results.keys()
    for key, a in off.results.items():
        b = on.results[key]
        assert np.asarray(a.pose).tobytes() == np.asarray(b.pose).tobytes(), key
        assert (a.score, a.flags) == (b.score, b.flags), key
