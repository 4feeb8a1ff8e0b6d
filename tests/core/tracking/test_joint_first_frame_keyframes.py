"""Joint tracking's first frame subtracts the bones not yet registered at their keyframes of the frame
(:data:`core.tracking.frame_step.JOINT_KEYFRAMES`), as sequential tracking does; frames without a
keyframe are registered as before (ideal 128² views of the talus and calcaneus, CPU device).

With the keyframes at the true poses the talus, registered first, had nothing subtracted before and
ended 0.234 mm / 0.513° from the truth; with the calcaneus subtracted at its keyframe 0.0003 mm /
0.003° (the calcaneus 0.0077 mm / 0.0065° and 0.0005 mm / 0.0021°). From keyframes 1 mm / 1° off
the truth (two random directions) the talus went from 0.243 mm / 0.397° and 0.261 mm / 0.335° to
0.093 mm / 0.211° and 0.080 mm / 0.258°, the poses sequential tracking with ``sequential_subtract``
gives (this 2-core x86_64 machine)."""

from __future__ import annotations

import numpy as np

from core.tracking.register import RegistrationOptions

REG = RegistrationOptions(bounds=(5.0, 5.0), sigma=(1.0, 1.0), search="newton")


def _error(P, truth, center) -> tuple[float, float]:
    from core.tracking.checks import pose_delta

    d = pose_delta(truth, P, center)
    return float(np.linalg.norm(d[:3])), float(np.rad2deg(np.linalg.norm(d[3:])))


def test_first_frame_subtracts_keyframes_as_sequential(talus_calcaneus_128, monkeypatch):
    import core.tracking.frame_step as fs
    from core.tracking.trial import TrackingOptions, track

    sc, models, r, frames = talus_calcaneus_128
    keys = {m.name: {0: sc.poses(0)[k]} for k, m in enumerate(models)}
    joint = TrackingOptions(mode="joint", joint_rounds=1, verify_restarts=0, registration=REG)
    new = track(r, models, frames.__getitem__, [0], keyframes=keys, options=joint)
    seq = track(r, models, frames.__getitem__, [0], keyframes=keys,
                options=TrackingOptions(mode="sequential", sequential_subtract=True, verify_restarts=0,
                                        registration=REG))
    monkeypatch.setattr(fs, "JOINT_KEYFRAMES", False)
    old = track(r, models, frames.__getitem__, [0], keyframes=keys, options=joint)
    talus = models[0]
    for m in models:  # the first frame as sequential tracking registers it
        np.testing.assert_array_equal(new.results[(m.name, 0)].pose, seq.results[(m.name, 0)].pose)
    e_new = _error(new.results[("talus", 0)].pose, sc.poses(0)[0], talus.centroid)
    e_old = _error(old.results[("talus", 0)].pose, sc.poses(0)[0], talus.centroid)
    assert e_new[0] < 0.02 and e_new[1] < 0.05  # 0.0003 mm, 0.003°
    assert e_old[0] > 0.1 and e_old[1] > 0.2  # 0.234 mm, 0.513°: nothing subtracted
    e_cal = _error(new.results[("calcaneus", 0)].pose, sc.poses(0)[1], models[1].centroid)
    assert e_cal[0] < 0.02 and e_cal[1] < 0.05


def test_frames_without_keyframes_unchanged(talus_calcaneus_128, monkeypatch):
    """Frame 1 tracked from frame 0's given poses (keyframes at frame 0 only): the same poses, bit for
    bit, with the keyframes subtracted or not."""
    import core.tracking.frame_step as fs
    from core.tracking.trial import TrackingOptions, track

    sc, models, r, frames = talus_calcaneus_128
    keys = {m.name: {0: sc.poses(0)[k]} for k, m in enumerate(models)}
    given = {m.name: {0: sc.poses(0)[k]} for k, m in enumerate(models)}
    o = TrackingOptions(mode="joint", joint_rounds=1, verify_restarts=0, registration=REG)
    new = track(r, models, frames.__getitem__, [0, 1], keyframes=keys, options=o, skip=given)
    monkeypatch.setattr(fs, "JOINT_KEYFRAMES", False)
    old = track(r, models, frames.__getitem__, [0, 1], keyframes=keys, options=o, skip=given)
    for m in models:
        np.testing.assert_array_equal(new.results[(m.name, 1)].pose, old.results[(m.name, 1)].pose)
