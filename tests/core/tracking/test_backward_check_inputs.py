"""The first frame's backward registration (:mod:`core.tracking.backward_check`) with a stubbed frame step
(no rendering): what it subtracts where a neighbour's first frame was given as a pose, and a run resumed
with every frame taken back — its first frame carrying the trajectory post-pass's flag, later frames
theirs — judged as the uninterrupted run judged it."""

from __future__ import annotations

import numpy as np

from tests.core.tracking.track_helpers import C, walking_track


def _run(monkeypatch, P: dict, turn: dict, *, skip=None, frames=range(20), keyframes=None, options=None):
    """track() of the bones of ``P`` (name -> (n, 4, 4) poses) with a frame step returning ``P``'s pose
    of the frame, and a bone's first frame turned by ``turn[name]`` degrees about z when registered again;
    (result, the calls' (frame, todo, {bone: skip's entry of the frame}, {bone: history frames}))."""
    from core.geometry.transforms import pose_from_params
    from core.tracking import trial
    from core.tracking.results import FrameResult

    names = list(P)
    calls = []

    def step(run, f, imgs, frame, todo, state, skip_):
        calls.append((f, list(todo), {b: skip_[b].get(f) for b in names},
                      {b: [g for g, _ in state[b].history] for b in names}))
        out = {}
        for i in todo:
            b = names[i]
            pose = P[b][f]
            if f == frames[0] and state[b].history:  # the backward registration
                pose = pose_from_params(np.r_[0, 0, 0, 0, 0, np.radians(turn[b])], center=C, base=pose)
            out[i] = FrameResult(b, f, pose, 0.8, 10, 0.0, True)
        return out

    class _Bone:
        def __init__(self, name):
            self.name, self.centroid = name, C

    class _Renderer:
        volumes = (None,) * len(names)

    monkeypatch.setattr(trial, "track_frame", step)
    kf = keyframes if keyframes is not None else {b: {frames[0]: P[b][frames[0]]} for b in names}
    res = trial.track(_Renderer(), [_Bone(b) for b in names], lambda f: [np.zeros((4, 4))], frames,
                      keyframes=kf, skip=skip, options=options)
    return res, calls


def test_neighbour_given_as_a_pose_subtracted(monkeypatch):
    """The talus's first frame given as a pose (a hand fix taken back on resume), the tibia's tracked: the
    backward registration of the tibia has the talus's given pose in the frame, as the forward pass had."""
    P = {"tibia": walking_track(20, (0.01, 0.05), 1), "talus": walking_track(20, (0.01, 0.05), 2)}
    given = P["talus"][0] + 0.0
    res, calls = _run(monkeypatch, P, {"tibia": 0.01, "talus": 0.01}, skip={"talus": {0: given}})
    f, todo, skip_, hist = calls[-1]
    assert f == 0 and todo == [0]  # the tibia alone registered again
    np.testing.assert_array_equal(skip_["talus"], given)
    assert hist["talus"] == [0] and hist["tibia"] == list(range(10, 0, -1))
    # the forward pass's first frame had it the same way (track adds a given pose to the history first)
    assert calls[0][0] == 0 and calls[0][3]["talus"] == [0]
    assert res.results[("tibia", 0)].notes[0].startswith("first frame registered again backward")


def test_resumed_complete_run_judged_alike(monkeypatch):
    """A complete run resumed with every frame taken back as it was journaled, the trajectory flag on the
    first frame and on frames 3 and 7 (as a batch's trajectory pass over the ranges together may leave
    them), gives the uninterrupted run's flags and notes: the check's scale leaves the post-pass's flags
    out, and a first frame carrying the trajectory flag is checked again (3f518d7). Interrupted after frame
    9 (the journal then without either post-pass's flag or note), resumed: the same."""
    import core.tracking.backward_check as bc
    from core.tracking.flags_post import FLAG as TRAJECTORY

    P = {"tibia": walking_track(20, (0.01, 0.05), 1)}
    full, _ = _run(monkeypatch, P, {"tibia": 0.01})
    first = full.results[("tibia", 0)]
    assert not first.flags and first.notes[0].startswith(bc.NOTE) and "limits" in first.notes[0]
    journal = {f: full.results[("tibia", f)] for f in range(20)}
    for f in (0, 3, 7):
        journal[f] = _with(journal[f], flags=(*journal[f].flags, f"{TRAJECTORY} (as journaled)"))
    again, calls = _run(monkeypatch, P, {"tibia": 0.01}, skip={"tibia": journal})
    assert [c[0] for c in calls] == [0]  # the backward registration alone
    for key, fr in full.results.items():
        assert again.results[key].flags == fr.flags and again.results[key].notes == fr.notes, key
    # interrupted after frame 9: the frames journaled so far without any post-pass's flag or note
    part = {"tibia": {f: _with(full.results[("tibia", f)], flags=(), notes=(), timing=None)
                      for f in range(10)}}
    again, _ = _run(monkeypatch, P, {"tibia": 0.01}, skip=part)
    for key, fr in full.results.items():
        assert again.results[key].flags == fr.flags and again.results[key].notes == fr.notes, key


def _with(fr, **kw):
    from dataclasses import replace

    return replace(fr, **kw)



def test_later_frame_given_as_a_pose(monkeypatch):
    """A frame after the first given as a pose (a hand fix taken back on resume; a numpy array, which has
    ``flags`` of its own) feeds the backward prediction as a good pose, as it fed the forward guesses."""
    P = {"tibia": walking_track(20, (0.01, 0.05), 1)}
    res, calls = _run(monkeypatch, P, {"tibia": 0.01}, skip={"tibia": {2: P["tibia"][2] + 0.0}})
    f, todo, _, hist = calls[-1]
    assert f == 0 and todo == [0] and hist["tibia"] == list(range(10, 0, -1))
    assert "from the constant-velocity prediction of frames 1 and 2" in res.results[("tibia", 0)].notes[0]


def test_limit_is_the_runs_option_and_none_turns_the_check_off(monkeypatch):
    """``TrackingOptions.backward_limit``: the first frame's backward registration 0.3 deg off (6x the
    track's noise) is flagged at the default 1.25 x the median, noted at 10 x (the limit named in the
    note); None: no backward registration, no flag or note."""
    from core.tracking.backward_check import FLAG, NOTE
    from core.tracking.trial import TrackingOptions

    P = {"tibia": walking_track(20, (0.01, 0.05), 1)}
    res, calls = _run(monkeypatch, P, {"tibia": 0.3})
    assert res.results[("tibia", 0)].flags[0].startswith(FLAG) and len(calls) == 21
    assert "1.25 x the bone's median trajectory residual" in res.results[("tibia", 0)].flags[0]
    res, _ = _run(monkeypatch, P, {"tibia": 0.3}, options=TrackingOptions(backward_limit=10))
    fr = res.results[("tibia", 0)]
    assert not fr.flags and fr.notes[0].startswith(NOTE) and "10 x the bone's median" in fr.notes[0]
    res, calls = _run(monkeypatch, P, {"tibia": 0.3}, options=TrackingOptions(backward_limit=None))
    fr = res.results[("tibia", 0)]
    assert len(calls) == 20 and not fr.flags and not fr.notes
    assert "backward_evaluations" not in (fr.timing or {})


def test_note_names_the_guess_the_backward_registration_started_from(monkeypatch):
    """The note says where the frame step started the backward registration, as the run's guess: the
    constant-velocity prediction of the two nearest frames, the pose of the nearest (``"previous"``), or
    the spline through the bone's other keyframes where they lie on both sides of the first frame
    (``"spline"``; without them the spline guess is the velocity one)."""
    from core.tracking.backward_check import _source
    from core.tracking.trial import TrackingOptions

    P = {"tibia": walking_track(30, (0.01, 0.05), 1)}
    frames = range(10, 30)
    notes = {}
    for guess, kf in (("velocity", (10,)), ("previous", (10,)), ("spline", (10,)), ("spline", (4, 10, 16)),
                      ("spline", (0, 4, 10, 16, 22, 28))):
        res, _ = _run(monkeypatch, P, {"tibia": 0.01}, frames=frames, options=TrackingOptions(guess=guess),
                      keyframes={"tibia": {k: P["tibia"][k] for k in kf}})
        notes[(guess, len(kf))] = res.results[("tibia", 10)].notes[0]
    assert "from its registration from the constant-velocity prediction of frames 11 and 12;" in notes[
        ("velocity", 1)]
    assert "from its registration from the pose of frame 11;" in notes[("previous", 1)]
    assert "from the constant-velocity prediction of frames 11 and 12;" in notes[("spline", 1)]
    assert "from its registration from the spline guess through keyframes 4, 16;" in notes[("spline", 3)]
    assert "spline guess through keyframes 0, 4, ..., 28;" in notes[("spline", 6)]
    # backward range (frames 12 down to 0): its nearest frames are below it
    assert _source("velocity", {}, 12, 11, 10).endswith("prediction of frames 11 and 10")

