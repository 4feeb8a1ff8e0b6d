"""Joint tracking's first frame (ideal 128² views of the talus and calcaneus, CPU device, one round):
the talus, registered first, has nothing subtracted. Two switches of :mod:`core.tracking.frame_step`,
both off by default: :data:`~core.tracking.frame_step.JOINT_KEYFRAMES` subtracts the calcaneus at its
keyframe, as sequential tracking does — better from keyframes at the truth, worse from keyframes
5 mm / 5° off (the acceptance study's); :data:`~core.tracking.frame_step.FIRST_FRAME_SECOND_ROUND`
registers the first frame's bones a second time with their neighbours at their round-0 poses — better
from 5 mm / 5°. Frames after the first are registered as before with either."""

from __future__ import annotations

import numpy as np
import pytest

from core.tracking.register import RegistrationOptions

REG = RegistrationOptions(bounds=(5.0, 5.0), sigma=(1.0, 1.0), search="newton")


def _error(P, truth, center) -> tuple[float, float]:
    from core.tracking.checks import pose_delta

    d = pose_delta(truth, P, center)
    return float(np.linalg.norm(d[:3])), float(np.rad2deg(np.linalg.norm(d[3:])))


def _off_keyframes(sc, models) -> dict:
    """Keyframes 5 mm / 5° off the truth (random directions; a draw where subtracting them harms)."""
    from core.geometry.transforms import pose_from_params

    g = np.random.default_rng(8)
    out = {}
    for k, m in enumerate(models):
        for _ in range(2):  # the second draw
            d, a = g.normal(size=3), g.normal(size=3)
        p = np.r_[d / np.linalg.norm(d) * 5.0, a / np.linalg.norm(a) * np.radians(5.0)]
        out[m.name] = {0: pose_from_params(p, center=m.centroid, base=sc.poses(0)[k])}
    return out


def test_keyframes_subtracted_help_near_the_truth_only(talus_calcaneus_128, monkeypatch):
    import core.tracking.frame_step as fs
    from core.tracking.trial import TrackingOptions, track

    sc, models, r, frames = talus_calcaneus_128
    monkeypatch.setattr(fs, "FIRST_FRAME_SECOND_ROUND", False)  # one round in the first frame, as measured
    monkeypatch.setattr(fs, "SEQUENTIAL_SECOND_PASS", False)  # (and one sequential pass, compared with it)
    true_keys = {m.name: {0: sc.poses(0)[k]} for k, m in enumerate(models)}
    joint = TrackingOptions(mode="joint", joint_rounds=1, verify_restarts=0, registration=REG)
    seq = TrackingOptions(mode="sequential", sequential_subtract=True, verify_restarts=0, registration=REG)

    def talus(keys, o=joint):
        res = track(r, models, frames.__getitem__, [0], keyframes=keys, options=o)
        return res, _error(res.results[("talus", 0)].pose, sc.poses(0)[0], models[0].centroid)

    _, e_old = talus(true_keys)
    monkeypatch.setattr(fs, "JOINT_KEYFRAMES", True)
    new, e_new = talus(true_keys)
    s, _ = talus(true_keys, seq)
    for m in models:  # the first frame as sequential tracking registers it
        np.testing.assert_array_equal(new.results[(m.name, 0)].pose, s.results[(m.name, 0)].pose)
    assert e_old[0] > 0.1 and e_old[1] > 0.2  # 0.234 mm, 0.513°: nothing subtracted
    assert e_new[0] < 0.02 and e_new[1] < 0.05  # 0.0003 mm, 0.003°
    off = _off_keyframes(sc, models)
    _, e_on = talus(off)  # the calcaneus subtracted 5 mm / 5° from where it is
    monkeypatch.setattr(fs, "JOINT_KEYFRAMES", False)
    _, e_off = talus(off)
    assert e_on[1] > 1.0 > 0.5 > e_off[1]  # 2.63° against 0.36° (0.342 / 0.266 mm)


@pytest.mark.parametrize("switch", ["JOINT_KEYFRAMES", "FIRST_FRAME_SECOND_ROUND"])
def test_second_round_in_the_first_frame_and_later_frames_unchanged(talus_calcaneus_128, monkeypatch, switch):
    import core.tracking.frame_step as fs
    from core.tracking.trial import TrackingOptions, track

    sc, models, r, frames = talus_calcaneus_128
    o = TrackingOptions(mode="joint", joint_rounds=1, verify_restarts=0, registration=REG)
    keys = {m.name: {0: sc.poses(0)[k]} for k, m in enumerate(models)}
    given = {m.name: {0: sc.poses(0)[k]} for k, m in enumerate(models)}  # frame 1 from frame 0's poses
    monkeypatch.setattr(fs, "FIRST_FRAME_SECOND_ROUND", False)  # both switches off, then one on
    old = track(r, models, frames.__getitem__, [0, 1], keyframes=keys, options=o, skip=given)
    monkeypatch.setattr(fs, switch, True)
    new = track(r, models, frames.__getitem__, [0, 1], keyframes=keys, options=o, skip=given)
    for m in models:
        np.testing.assert_array_equal(new.results[(m.name, 1)].pose, old.results[(m.name, 1)].pose)
    if switch == "FIRST_FRAME_SECOND_ROUND":  # from keyframes 5 mm / 5° off: the talus a second time
        off = _off_keyframes(sc, models)
        res = track(r, models, frames.__getitem__, [0], keyframes=off, options=o)
        e = _error(res.results[("talus", 0)].pose, sc.poses(0)[0], models[0].centroid)
        monkeypatch.setattr(fs, switch, False)
        res0 = track(r, models, frames.__getitem__, [0], keyframes=off, options=o)
        e0 = _error(res0.results[("talus", 0)].pose, sc.poses(0)[0], models[0].centroid)
        assert e[0] < 0.05 and e[1] < 0.05 < 0.1 < e0[1]  # 0.0013 mm / 0.0048° against 0.266 / 0.357
