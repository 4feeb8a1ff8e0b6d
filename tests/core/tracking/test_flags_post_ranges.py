"""The trajectory post-pass over frame ranges (core.tracking.flags_post): a range run fits through
the journal's good poses outside it (its ends two-sided, a short range judged) and never flags
them; ``talus batch`` judges a trial's ranges together once all are done, so the flags do not
depend on the order the range tasks ran. Synthetic poses: no rendering."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

from core.study.results import append_pose, read_journal
from core.tracking import trial
from core.tracking.batch import TaskSettings
from core.tracking.flags_post import FLAG, journal_neighbours
from core.tracking.results import FrameResult
from tests.core.tracking.test_flags_post import C, _track


@pytest.fixture(autouse=True)
def _trajectory_pass_alone(monkeypatch):
    """These tests judge the trajectory post-pass alone: the first frame's backward registration
    (:mod:`core.tracking.backward_check`, tests of its own) off."""
    from core.tracking import backward_check

    monkeypatch.setattr(backward_check, "backward_check", lambda *a, **k: [])  # as backward_limit=None


class _Bone:
    name, centroid = "tibia", C


class _Renderer:
    volumes = (None,)


def _run(monkeypatch, P, frames, neighbours=None):
    """track() over ``frames`` whose registrations return ``P``'s poses; (result, recorded again)."""
    monkeypatch.setattr(trial, "track_frame",
                        lambda run, f, imgs, fr, todo, state, skip: {0: FrameResult("tibia", f, P[f], 0.8, 10,
                                                                                    0.0, True)})
    seen = []
    res = trial.track(_Renderer(), [_Bone()], lambda f: [np.zeros((4, 4))], frames,
                      keyframes={"tibia": {int(frames[0]): P[frames[0]]}}, record_result=seen.append,
                      neighbours=neighbours)
    return res, seen[len(frames):]


def _journal(tmp_path, P, frames, flagged=()):
    """A bone journal holding ``P``'s poses at ``frames`` as tracking results (``flagged`` with a
    review flag), read back."""
    path = tmp_path / "tibia.jsonl"
    for f in frames:
        fl = ("score drop (test)",) if f in flagged else ()
        fr = FrameResult("tibia", int(f), P[f], 0.8, 10, 0.0, not fl, fl)
        append_pose(path, int(f), P[f], score=0.8, tracking=fr.journal_fields())
    return read_journal(path)


def test_a_range_run_fits_its_ends_through_the_journal_and_never_flags_it(monkeypatch, tmp_path):
    # frame 10 opens the range 10-19, 0.5 deg off (10x the noise); frame 30, outside, as far off
    P = _track(n=40, off=(10, 0.0, 0.5))
    P[30] = _track(n=40, off=(30, 0.0, 0.5))[30]
    rng = list(range(10, 20))
    alone, again = _run(monkeypatch, P, rng)
    # alone: fitted from one side, through the 8 frames after it (flags_ends; the parabola through the 4
    # after it, extrapolated, left it within its wide residual)
    assert [r.frame for r in alone.flagged] == [10] and [r.frame for r in again] == [10]
    state = _journal(tmp_path, P, [f for f in range(40) if f not in rng], flagged=(5,))
    near = journal_neighbours({"tibia": state}, rng)
    assert sorted(near["tibia"]) == [f for f in range(40) if f not in rng and f != 5]  # good poses only
    res, again = _run(monkeypatch, P, rng, neighbours=near)
    assert [r.frame for r in res.flagged] == [10] and res.results[("tibia", 10)].flags[0].startswith(FLAG)
    assert [r.frame for r in again] == [10]  # journaled again: the run's own frames only (not 30)
    assert set(res.frames) == set(rng) and ("tibia", 30) not in res.results
    # backward over the same range: the same flags
    back, _ = _run(monkeypatch, P, rng[::-1], neighbours=near)
    assert [r.frame for r in back.flagged] == [10]


def test_a_short_range_is_judged_thanks_to_its_neighbours(monkeypatch, tmp_path):
    from core.tracking.flags_post import MIN_FRAMES

    P = _track(n=40, off=(22, 0.0, 0.3))
    rng = list(range(20, 25))
    assert len(rng) < MIN_FRAMES
    alone, _ = _run(monkeypatch, P, rng)
    assert not alone.flagged  # too few frames to judge
    state = _journal(tmp_path, P, [f for f in range(40) if f not in rng])
    res, again = _run(monkeypatch, P, rng, neighbours=journal_neighbours({"tibia": state}, rng))
    # frame 21, good, stands off the same way as 22 without it (the noise's draw): flagged with it
    assert [r.frame for r in res.flagged] == [21, 22] and [r.frame for r in again] == [21, 22]
    assert res.results[("tibia", 21)].flags[0].startswith(f"{FLAG} next to flagged frame 22, the same way")
    # hand fixes in the range (skip's poses) are neighbours too, never judged
    monkeypatch.setattr(trial, "track_frame",
                        lambda run, f, imgs, fr, todo, state, skip: {0: FrameResult("tibia", f, P[f], 0.8, 10,
                                                                                    0.0, True)})
    res = trial.track(_Renderer(), [_Bone()], lambda f: [np.zeros((4, 4))], range(10, 30),
                      keyframes={"tibia": {10: P[10]}}, skip={"tibia": {22: P[22]}})
    assert not res.flagged and ("tibia", 22) not in res.results


def test_smooth_neighbours_do_not_shrink_a_ranges_scale(monkeypatch):
    # poses outside the range that are not this tracker's (an imported, filtered trajectory; poses
    # set by hand) are smooth: in the bone's median they took the limit down to the floor, and 8
    # of 10 good frames of the range were flagged; a range of MIN_FRAMES frames or more is scaled
    # by its own frames' residuals (the fits still run through the neighbours)
    P = _track(n=100, seed=3)
    smooth = _track(n=100, noise=(0.0, 0.0), seed=3)
    rng = list(range(40, 50))
    near = {"tibia": {f: smooth[f] for f in range(100) if f not in rng}}
    res, _ = _run(monkeypatch, P, rng, neighbours=near)
    assert not res.flagged
    Q = P.copy()
    Q[45] = _track(n=100, seed=3, off=(45, 0.0, 0.5))[45]  # a frame 10x its noise off: still caught
    res, _ = _run(monkeypatch, Q, rng, neighbours=near)
    assert [r.frame for r in res.flagged] == [45]


BONE = "talus"
SETTINGS = TaskSettings(device="cpu", confidence=False)  # the registration itself is replaced


def _fake_registration(P):
    """A registration that returns ``P``'s pose of the frame (both ranges that track a shared
    keyframe get the same pose, as a real one does)."""
    def frame(run, f, imgs, fr, todo, state, skip):
        return {0: FrameResult(BONE, f, P[f], 0.8, 10, 0.0, True)}
    return frame


def test_batch_ranges_are_judged_together_whatever_their_order(keyed, tmp_path, monkeypatch):
    from core.study import Study
    from core.tracking import batch

    # smooth noisy poses, the shared keyframe 12 0.4 deg off (8x the noise), frame 13 0.3 deg
    P = _track(n=30, off=(12, 0.0, 0.4))
    P[13] = _track(n=30, off=(13, 0.0, 0.3))[13]
    monkeypatch.setattr(trial, "track_frame", _fake_registration(P))

    def flags(folder):
        with Study.open(folder) as st:
            recs = st.trial("walk").results(BONE).records
        return {f: tuple(r.tracking["flags"]) for f, r in recs.items() if r.tracking}

    def run(name, reverse):
        folder = shutil.copytree(keyed, tmp_path / name)
        tasks = batch.build_tasks([folder], bones=[BONE], ranges=True)
        assert [t.frames for t in tasks] == [(12, 0), (12, 29)]
        summaries[name] = batch.run_serial(tasks[::-1] if reverse else tasks, SETTINGS)
        got[name] = flags(folder)

    got, summaries = {}, {}
    with monkeypatch.context() as m:  # each range task's own pass only
        m.setattr(batch, "trajectory_pass", lambda *a, **k: [])
        run("forward-ranges", False)
        run("reverse-ranges", True)
    # 12-29 run first judges its start from one side (13 not flagged), and 12-0 after it does not
    # track 13: the flags depended on which range ran first
    flagged = {k: sorted(f for f, fl in got[k].items() if fl) for k in got}
    assert flagged["forward-ranges"] == [12, 13] and flagged["reverse-ranges"] == [12]
    for name, reverse in (("forward", False), ("reverse", True)):
        run(name, reverse)
    assert summaries["forward"]["status"] == "complete"
    assert sorted(got["forward"]) == list(range(30))
    assert got["forward"] == got["reverse"]
    assert sorted(f for f, fl in got["forward"].items() if fl) == [12, 13]
    assert got["forward"][12][0].startswith(FLAG)
    (entry,) = summaries["forward"]["trajectory_pass"]
    assert entry["key"] == "forward/walk/talus" and entry["judged"] == 30 and entry["flagged"] >= 1
    # once more: nothing changes
    with Study.open(tmp_path / "forward") as st:
        tasks = batch.build_tasks([st.folder], bones=[BONE], ranges=True)
    records = [{"key": t.key, "status": "complete"} for t in tasks]
    (again,) = batch.trajectory_pass(tasks, records, SETTINGS)
    assert again["changed"] == [] and flags(tmp_path / "forward") == got["forward"]
