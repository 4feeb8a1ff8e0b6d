"""The first frame registered again backward (:mod:`core.tracking.backward_check`) on ideal 128² views of
the talus and calcaneus over three frames (Warp's CPU device): sequential tracking with one pass in the
first frame (:data:`core.tracking.frame_step.SEQUENTIAL_SECOND_PASS` off), from keyframes 5 mm / 5° off,
leaves the talus's first frame degrees off, unflagged (the calcaneus, subtracted at its keyframe, is
where it is not); the frames after it are registered from it and come back to the truth. Registered
again from the prediction of frames 2 and 1, the talus lands elsewhere and its first frame is flagged;
the calcaneus's agrees and gets the note. Ground truth in the test only."""

from __future__ import annotations

import numpy as np
import pytest

from tests.core.tracking.test_joint_first_frame_keyframes import REG, _error, _off_keyframes


@pytest.fixture(scope="module")
def three_frames():
    from core.render import DRRRenderer
    from core.synthetic import make_foot_scene
    from core.tracking.bones import bone_model

    sc = make_foot_scene(n_frames=3, pixels=128, spacing=1.5, names=("talus", "calcaneus"), beads_per_bone=0,
                         phase=(0.0, 0.045), soft_tissue=False, imaging="ideal", floor_thickness_mm=0)
    models = [bone_model(b, mesh=False) for b in sc.bones]
    r = DRRRenderer(sc.rig, [b.to_attenuation(sc.bone_transfer) for b in sc.bones], device="cpu")
    frames = {i: [m.to_float(f) for m, f in zip(sc.imaging, sc.render_frame(i), strict=True)]
              for i in range(3)}
    return sc, models, r, frames


def _options():
    from core.tracking.trial import TrackingOptions

    return TrackingOptions(mode="sequential", sequential_subtract=True, verify_restarts=0, registration=REG,
                           trajectory_limit=None)


def _errors(res, sc, models) -> dict:
    return {m.name: [_error(res.results[(m.name, f)].pose, sc.poses(f)[k], m.centroid) for f in range(3)]
            for k, m in enumerate(models)}


def test_first_frame_off_flagged_backward(three_frames, monkeypatch):
    import core.tracking.backward_check as bc
    import core.tracking.frame_step as fs
    from core.tracking.trial import track

    sc, models, r, frames = three_frames
    monkeypatch.setattr(fs, "SEQUENTIAL_SECOND_PASS", False)
    off = _off_keyframes(sc, models)
    recorded = []
    assert bc.BACKWARD_CHECK  # the default
    # a scale as the trajectory check's median residual of a longer run (three frames have none)
    monkeypatch.setattr(bc, "_scale", lambda *a: np.array([0.04, 0.12]))
    res = track(r, models, frames.__getitem__, [0, 1, 2], keyframes=off, options=_options(),
                record_result=recorded.append)
    err = _errors(res, sc, models)
    # the talus's first frame 0.342 mm / 2.63° off, its frames 1 and 2 0.10° and 0.25°; the calcaneus's
    # 0.030 mm / 0.070° off, its frames 1 and 2 0.002 mm / 0.006°: registered again from frames 2 and 1,
    # the talus 0.353 mm / 2.44° and the calcaneus 0.032 mm / 0.063° from their first frames
    assert err["talus"][0][1] > 1.0 and max(e[1] for e in err["talus"][1:]) < 0.5
    assert err["calcaneus"][0][1] > 5 * max(e[1] for e in err["calcaneus"][1:])
    talus, calc = res.results[("talus", 0)], res.results[("calcaneus", 0)]
    assert len(talus.flags) == 1 and talus.flags[0].startswith(bc.FLAG) and talus.converged
    assert "from the prediction of frames 2, 1; limits 0.100 mm, 0.300 deg" in talus.flags[0]
    assert not calc.flags and len(calc.notes) == 1 and calc.notes[0].startswith(bc.NOTE)
    for m in models:
        assert res.results[(m.name, 0)].timing["backward_evaluations"] > 0
        assert not res.results[(m.name, 1)].flags and not res.results[(m.name, 2)].flags
    # journaled again with the flag, after the frames' own records
    assert [(fr.bone, fr.frame) for fr in recorded[-2:]] == [("talus", 0), ("calcaneus", 0)]
    assert recorded[-2].flags == talus.flags and recorded[-1].notes == calc.notes
    # off: the same poses, the first frames silent
    monkeypatch.setattr(bc, "BACKWARD_CHECK", False)
    old = track(r, models, frames.__getitem__, [0, 1, 2], keyframes=off, options=_options())
    for key, fr in old.results.items():
        np.testing.assert_array_equal(fr.pose, res.results[key].pose)
        assert not fr.flags and not fr.notes


def test_short_run_not_judged(three_frames):
    """From true keyframes the talus's first frame is 0.0003 mm / 0.003° off, its third 0.080 mm / 0.240°:
    registered again from frames 2 and 1, 0.075 mm / 0.233° from the first. Three frames give no
    trajectory scale: noted, not flagged."""
    import core.tracking.backward_check as bc
    from core.tracking.trial import track

    sc, models, r, frames = three_frames
    true = {m.name: {0: sc.poses(0)[k]} for k, m in enumerate(models)}
    res = track(r, models, frames.__getitem__, [0, 1, 2], keyframes=true, options=_options())
    for m in models:
        fr = res.results[(m.name, 0)]
        assert not fr.flags and len(fr.notes) == 1 and fr.notes[0].startswith(f"{bc.NOTE}: not judged")
        assert "fewer than 8 of the bone's frames with a trajectory residual" in fr.notes[0]
