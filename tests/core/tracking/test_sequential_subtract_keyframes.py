"""Sequential tracking with the neighbours subtracted (TrackingOptions.sequential_subtract) in a run
started from keyframes: a bone with a keyframe in the frame is subtracted at it until it is
registered there — the first bone of the first frame no longer gets nothing subtracted — while
joint tracking is the same as before (ideal 128² views of the talus and calcaneus, Warp's CPU
device)."""

from __future__ import annotations

import numpy as np

from tests.core.tracking.test_sequential_search_neighbours import _run as _run_from_keyframes
from tests.core.tracking.test_sequential_search_neighbours import assert_same_results


def _run(scene, monkeypatch, *, mode: str, subtract: bool):
    # frame 0 registered too (not skipped): the keyframes are where the searches start
    return _run_from_keyframes(scene, monkeypatch, mode=mode, subtract=subtract, skip=False)


def test_keyframe_neighbour_subtracted_in_the_first_frame(talus_calcaneus_128, monkeypatch):
    import core.tracking.frame_step as fs

    monkeypatch.setattr(fs, "SEQUENTIAL_SECOND_PASS", False)  # the first pass (the second: its own test)
    sc = talus_calcaneus_128[0]
    res, seen = _run(talus_calcaneus_128, monkeypatch, mode="sequential", subtract=True)
    (b0, o0, a0), (b1, o1, a1), (b2, o2, _), (b3, o3, _) = seen
    assert (b0, b1, b2, b3) == (0, 1, 0, 1)
    # frame 0: the talus with the calcaneus at its keyframe (before: nothing subtracted) ...
    assert o0[1] == [1] and np.array_equal(o0[0][0], sc.poses(0)[1])
    # ... then the calcaneus with the talus just registered (not its keyframe)
    assert o1[1] == [0] and np.array_equal(o1[0][0], a0.result.pose)
    # frame 1 (no keyframe): the calcaneus at its guess, then the talus registered, as before
    assert o2[1] == [1] and np.array_equal(o2[0][0], a1.result.pose)
    assert o3[1] == [0]
    for k, m in enumerate(talus_calcaneus_128[1]):
        for f in (0, 1):
            d = res.results[(m.name, f)].pose[:3, 3] - sc.poses(f)[k][:3, 3]
            assert np.linalg.norm(d) < 1.0  # registered (ideal 128² views, 1.5 mm voxels)


def test_keyframes_not_subtracted_when_off(talus_calcaneus_128, monkeypatch):
    _, seen = _run(talus_calcaneus_128, monkeypatch, mode="sequential", subtract=False)
    assert [s[0] for s in seen] == [0, 1, 0, 1]
    assert all(s[1] is None for s in seen)


def test_joint_tracking_from_keyframes_unchanged(talus_calcaneus_128, monkeypatch):
    """Joint tracking's first frame: its first round subtracts only the bones registered before
    (not the keyframes), whatever sequential_subtract holds, and the poses are bit-equal."""
    off, seen = _run(talus_calcaneus_128, monkeypatch, mode="joint", subtract=False)
    assert seen[0][0] == 0 and seen[0][1] is None  # frame 0, round 0: the talus alone, as before
    on, _ = _run(talus_calcaneus_128, monkeypatch, mode="joint", subtract=True)
    assert_same_results(off, on)
