"""The first frame registered again backward (:mod:`core.tracking.backward_check`) on ideal 128² views of
the talus and calcaneus over three frames (Warp's CPU device): sequential tracking with one pass in the
first frame (:data:`core.tracking.frame_step.SEQUENTIAL_SECOND_PASS` off), from keyframes 5 mm / 5° off,
leaves the talus's first frame degrees off, unflagged (the calcaneus, subtracted at its keyframe, is
where it is not); the frames after it are registered from it and come back to the truth. Registered
again from the constant-velocity prediction of frames 1 and 2, the talus lands elsewhere and its first
frame is flagged; the calcaneus's agrees and gets the note. Ground truth in the test only."""

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
    assert _options().backward_limit == bc.LIMIT == 1.25  # the default
    # a scale as the trajectory check's median residual of a longer run (three frames have none)
    monkeypatch.setattr(bc, "_scale", lambda *a: np.array([0.08, 0.24]))
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
    assert ("from its registration from the constant-velocity prediction of frames 1 and 2; limits 0.100 mm, "
            "0.300 deg, 1.25 x the bone's median") in talus.flags[0]
    assert not calc.flags and len(calc.notes) == 1 and calc.notes[0].startswith(bc.NOTE)
    for m in models:
        assert res.results[(m.name, 0)].timing["backward_evaluations"] > 0
        assert not res.results[(m.name, 1)].flags and not res.results[(m.name, 2)].flags
    # journaled again with the flag, after the frames' own records
    assert [(fr.bone, fr.frame) for fr in recorded[-2:]] == [("talus", 0), ("calcaneus", 0)]
    assert recorded[-2].flags == talus.flags and recorded[-1].notes == calc.notes
    # off (TrackingOptions.backward_limit None): the same poses, the first frames silent
    from dataclasses import replace

    old = track(r, models, frames.__getitem__, [0, 1, 2], keyframes=off,
                options=replace(_options(), backward_limit=None))
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


def _fake_run(monkeypatch, P, back_turn_deg, skip=None, frames=range(20)):
    """track() with a frame step that returns ``P``'s pose of the frame, and the first frame's pose turned
    by ``back_turn_deg`` about z when registered again; (result, the calls' (frame, todo, history frames,
    keyframes of the frame))."""
    from core.geometry.transforms import pose_from_params
    from core.tracking import trial
    from core.tracking.results import FrameResult
    from tests.core.tracking.track_helpers import C

    calls = []

    def step(run, f, imgs, frame, todo, state, skip_):
        calls.append((f, list(todo), [g for g, _ in state["tibia"].history], dict(run.keyframes["tibia"])))
        pose = P[f]
        if f == 0 and state["tibia"].history:  # the backward registration
            pose = pose_from_params(np.r_[0, 0, 0, 0, 0, np.radians(back_turn_deg)], center=C, base=P[f])
        return {0: FrameResult("tibia", f, pose, 0.8, 10, 0.0, True)}

    class _Bone:
        name, centroid = "tibia", C

    class _Renderer:
        volumes = (None,)

    monkeypatch.setattr(trial, "track_frame", step)
    res = trial.track(_Renderer(), [_Bone()], lambda f: [np.zeros((4, 4))], frames,
                      keyframes={"tibia": {0: P[0]}}, skip=skip)
    return res, calls


def test_backward_registration_from_the_frames_after_it(monkeypatch):
    """The first frame's second registration: the frame step with the bone's later frames as its history in
    reverse order (frames 10 to 1, the prediction from 2 and 1), the first frame's keyframe not used; a turn
    of 0.3° (6x the track's noise) flagged, 0.01° noted. Synthetic poses: no rendering."""
    import core.tracking.backward_check as bc
    from tests.core.tracking.track_helpers import walking_track

    P = walking_track(20, (0.01, 0.05), 1)
    res, calls = _fake_run(monkeypatch, P, 0.3)
    assert [c[0] for c in calls] == [*range(20), 0]
    _, todo, hist, kf = calls[-1]
    assert todo == [0] and hist == list(range(10, 0, -1)) and 0 not in kf
    fr = res.results[("tibia", 0)]
    assert len(fr.flags) == 1 and fr.flags[0].startswith(bc.FLAG) and "0.300 deg" in fr.flags[0]
    assert "from the constant-velocity prediction of frames 1 and 2" in fr.flags[0]
    assert [r.frame for r in res.flagged] == [0]
    res, _ = _fake_run(monkeypatch, P, 0.01)
    fr = res.results[("tibia", 0)]
    assert not fr.flags and fr.notes[0].startswith(bc.NOTE) and "0.010 deg" in fr.notes[0]
    # resumed with the first frame flagged by the check: judged afresh (one flag), and fed the guesses
    res, _ = _fake_run(monkeypatch, P, 0.3)
    flagged = res.results[("tibia", 0)]
    again, calls = _fake_run(monkeypatch, P, 0.3, skip={"tibia": {0: flagged}})
    assert calls[0][0] == 1 and calls[0][2] == [0]  # frame 1 predicted from the restored first frame
    assert again.results[("tibia", 0)].flags == flagged.flags



def test_joint_run_checks_every_bone(three_frames, monkeypatch):
    """Joint tracking: both bones' first frames registered again in one frame step (each with the other at
    its prediction, as in any later frame) from frames 2 and 1; from true keyframes, three frames give no
    scale: noted, not judged."""
    import core.tracking.backward_check as bc
    from core.tracking import trial

    sc, models, r, frames = three_frames
    calls = []
    real = trial.track_frame

    def step(run, f, imgs, frame, todo, state, skip):
        calls.append((f, list(todo), {b: [g for g, _ in state[b].history] for b in run.names}))
        return real(run, f, imgs, frame, todo, state, skip)

    monkeypatch.setattr(trial, "track_frame", step)
    true = {m.name: {0: sc.poses(0)[k]} for k, m in enumerate(models)}
    o = trial.TrackingOptions(mode="joint", verify_restarts=0, registration=REG, trajectory_limit=None)
    res = trial.track(r, models, frames.__getitem__, [0, 1, 2], keyframes=true, options=o)
    assert [c[0] for c in calls] == [0, 1, 2, 0]
    assert calls[-1][1] == [0, 1] and calls[-1][2] == {"talus": [2, 1], "calcaneus": [2, 1]}
    for m in models:
        fr = res.results[(m.name, 0)]
        assert not fr.flags and len(fr.notes) == 1 and fr.notes[0].startswith(f"{bc.NOTE}: not judged")
        assert fr.timing["backward_evaluations"] > 0
