"""Resuming a tracking run from its journal gives the uninterrupted run's results and report
(review flags included); a cancelled frame is never recorded."""

import json
import random

import numpy as np

from core.geometry.transforms import pose_from_params
from core.study.results import append_pose, read_journal
from core.tracking.register import Level, RegistrationOptions
from core.tracking.trial import FrameResult, TrackingOptions, journal_inputs, track

FAST = TrackingOptions(registration=RegistrationOptions(
    bounds=(4.0, 4.0), levels=(Level(1.0, "cmaes", (0.7, 0.7), popsize=10, max_generations=40, tol_x=0.02),),
    refine="pattern"), confidence=False, verify_restarts=0)
VOLATILE = {"time_s", "timing", "time_per_frame_s"}


def _strip(obj):
    if isinstance(obj, dict):
        return {k: _strip(v) for k, v in obj.items() if k not in VOLATILE}
    if isinstance(obj, list):
        return [_strip(v) for v in obj]
    return obj


def _frames(w):
    return lambda i: w["frames"](40 if i == 2 else i)  # frame 2 shows another frame: flagged


def _run(w, path, order, *, cancel=None, options=FAST):
    kf, skip = journal_inputs({"talus": read_journal(path)}, order, resume=True)
    return track(w["renderer"], [w["model"]], _frames(w), order, keyframes=kf, skip=skip, options=options,
                 record_result=lambda fr: append_pose(path, fr.frame, fr.pose, score=fr.score,
                                                      tracking=fr.journal_fields()),
                 cancel=cancel)


def _start(w):
    sc, c = w["scene"], w["model"].centroid
    return pose_from_params(np.r_[1.5, -1.0, 1.0, 0.02, -0.02, 0.01], center=c, base=sc.poses(0)[0])


def test_cancel_during_the_last_frame_records_nothing_and_says_cancelled(walking_talus_64, tmp_path):
    w = walking_talus_64
    path = tmp_path / "talus.jsonl"
    append_pose(path, 0, _start(w))
    polls = {"n": 0}

    def cancel():  # fires in the middle of the last frame's registration
        if read_journal(path).done.keys() >= {0, 1}:
            polls["n"] += 1
        return polls["n"] > 8

    res = _run(w, path, [0, 1, 3], cancel=cancel)
    assert res.status == "cancelled" and polls["n"] > 8
    assert sorted(k[1] for k in res.results) == [0, 1]  # the unfinished frame is not reported ...
    assert sorted(read_journal(path).done) == [0, 1]  # ... nor journalled
    res = _run(w, path, [0, 1, 3])  # the resumed run registers it
    assert res.status == "complete" and sorted(read_journal(path).done) == [0, 1, 3]
    assert res.results[("talus", 3)].converged


def test_resumed_runs_rebuild_the_uninterrupted_report(walking_talus_64, tmp_path):
    """Stopped at random moments inside and after the flagged frame, then resumed: the report and
    journal equal the uninterrupted run's."""
    w = walking_talus_64
    order = [0, 1, 2, 3, 4]
    ref_path = tmp_path / "ref.jsonl"
    append_pose(ref_path, 0, _start(w))
    ref = _run(w, ref_path, order)
    flagged = [r.frame for r in ref.flagged]
    assert flagged == [2] and ref.results[("talus", 2)].retried  # the wrong images: flagged
    assert not ref.results[("talus", 3)].flags  # and not used for frame 3's guess
    expect = _strip(ref.report())
    rng = random.Random(5)
    # stopped inside the flagged frame (2 journalled) and after it (4); a stop inside an ordinary
    # frame is the cancel test's above (stopping after 1 too cost another third of this test's CPU)
    for k, stop_after in enumerate((2, 4)):
        path = tmp_path / f"run{k}.jsonl"
        append_pose(path, 0, _start(w))
        polls = {"n": 0, "at": rng.randrange(1, 60)}

        def cancel(path=path, polls=polls, stop_after=stop_after):
            if len(read_journal(path).done) >= stop_after:
                polls["n"] += 1
            return polls["n"] >= polls["at"]

        first = _run(w, path, order, cancel=cancel)
        assert first.status == "cancelled"
        res = _run(w, path, order)
        assert res.status == "complete"
        assert _strip(res.report()) == expect, stop_after
        a, b = read_journal(ref_path), read_journal(path)
        for f in order:
            np.testing.assert_array_equal(a.records[f].pose, b.records[f].pose)
            assert _strip(a.records[f].tracking) == _strip(b.records[f].tracking)


def test_restored_state_feeds_the_checks_and_the_guesses(walking_talus_64):
    """A resumed run refills the score history (the score-drop check fires as it would have)
    and does not start from a flagged frame."""
    w = walking_talus_64
    sc = w["scene"]
    good = {f: FrameResult("talus", f, sc.poses(f)[0], 2.0, 1, 0.0, True) for f in (0, 1)}
    res = track(w["renderer"], [w["model"]], w["frames"], [0, 1, 2], keyframes={"talus": {0: sc.poses(0)[0]}},
                skip={"talus": good}, options=FAST)
    fr = res.results[("talus", 2)]
    assert any(f.startswith("score drop") for f in fr.flags), fr.flags  # 1.0 < 0.85 x 2.0
    assert [r.frame for r in res.results.values()] == [0, 1, 2]  # the report holds the earlier frames
    far = sc.poses(1)[0].copy()
    far[:3, 3] += [30.0, 0, 0]
    skip = {"talus": {0: FrameResult("talus", 0, sc.poses(0)[0], 1.0, 1, 0.0, True),
                      1: FrameResult("talus", 1, far, 0.2, 1, 0.0, False, ("pose jump",))}}
    res = track(w["renderer"], [w["model"]], w["frames"], [0, 1, 2], keyframes={"talus": {0: sc.poses(0)[0]}},
                skip=skip, options=FAST)
    fr = res.results[("talus", 2)]
    assert fr.converged and not fr.flags and np.abs(fr.pose[:3, 3] - sc.poses(2)[0][:3, 3]).max() < 0.2
    assert [r.frame for r in res.flagged] == [1]


def test_journal_inputs_keyframes_are_the_hand_set_poses(tmp_path):
    path = tmp_path / "b.jsonl"
    P = [np.eye(4) for _ in range(4)]
    for k, T in enumerate(P):
        T[:3, 3] = k
    append_pose(path, 0, P[0])  # the user's start
    append_pose(path, 0, P[1], score=0.9,
                tracking=FrameResult("b", 0, P[1], 0.9, 5, 0.1, True).journal_fields())
    append_pose(path, 1, P[2], score=0.3,
                tracking=FrameResult("b", 1, P[2], 0.3, 5, 0.1, False, ("pose jump",)).journal_fields())
    append_pose(path, 9, P[3])  # outside the range: any pose is a keyframe
    st = {"b": read_journal(path)}
    kf, skip = journal_inputs(st, range(5), resume=True)
    assert sorted(kf["b"]) == [0, 9]
    np.testing.assert_array_equal(kf["b"][0], P[0])
    assert skip["b"][1].flags == ("pose jump",) and skip["b"][1].evaluations == 5 and skip["b"][0].converged
    kf2, skip2 = journal_inputs(st, range(5), resume=False)
    assert kf2 == kf and skip2 == {"b": {}}


def test_sigkill_at_random_moments_then_resume_matches_the_uninterrupted_run(tmp_path):
    """The crash/resume study at a small size: real SIGKILLs of a tracking subprocess."""
    from core.studies.crash_resume import study

    # 48² views: frame 3 is still flagged (score drop, pose jump); 22 s of CPU, subprocesses
    # included, against 30 s at 64²
    res = study(runs=1, n_frames=4, pixels=48, seed=3, max_kills=2, workdir=tmp_path)
    assert res["runs"][0]["kills"] >= 1 and res["identical"] == 1, json.dumps(res["differences"])
    assert res["case"]["flagged_in_reference"]
