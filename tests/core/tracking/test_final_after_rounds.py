"""The registrations' final stage in the frame step (core.tracking.frame_step): in joint tracking it
runs after the last round only — once per bone and frame, as in sequential tracking — on ideal 128²
views of the talus and calcaneus (CPU device)."""

from __future__ import annotations

import numpy as np
import pytest


@pytest.fixture(scope="module")
def two_bones(talus_calcaneus_128):
    return talus_calcaneus_128


def _track(two_bones, monkeypatch, *, mode: str, rounds: int = 2, lockstep: bool = True):
    """Frame 1 tracked from the true poses of frame 0; the final stage's runs as (bone, options)."""
    import core.tracking.final_stage as fst
    from core.tracking.register import RegistrationOptions
    from core.tracking.trial import TrackingOptions, track

    sc, models, r, frames = two_bones
    runs = []
    real = fst.final_stage

    def counted(renderer, frame, res, **k):
        if k["options"].final is not None:
            runs.append(k["bone"])
        return real(renderer, frame, res, **k)

    monkeypatch.setattr(fst, "final_stage", counted)
    skip = {m.name: {0: sc.poses(0)[k]} for k, m in enumerate(models)}
    reg = RegistrationOptions(bounds=(5.0, 5.0), sigma=(1.0, 1.0), search="newton", final_highpass_px=2.0)
    o = TrackingOptions(mode=mode, joint_rounds=rounds, lockstep=lockstep, verify_restarts=0,
                        registration=reg, refine_likelihood=True)
    res = track(r, models, frames.__getitem__, [0, 1], keyframes=skip, skip=skip, options=o)
    return res, runs


def _sane(res, n_bones: int) -> None:
    done = [fr for fr in res.results.values() if fr.frame == 1]
    assert len(done) == n_bones
    for fr in done:
        assert fr.pose is not None and np.all(np.isfinite(fr.pose)), fr
        assert np.isfinite(fr.score) and not fr.retried and not fr.flags, fr
        sig = np.asarray(fr.confidence["sigma"], dtype=float)
        assert np.all(np.isfinite(sig)) and np.all(sig > 0), fr.confidence
        assert fr.timing["likelihood_s"] > 0  # the pose and its σ are the stage's


@pytest.mark.parametrize("lockstep", [True, False], ids=["lockstep", "one_by_one"])
def test_joint_rounds_run_the_final_stage_once_per_bone(two_bones, monkeypatch, lockstep):
    res, runs = _track(two_bones, monkeypatch, mode="joint", rounds=2, lockstep=lockstep)
    assert sorted(runs) == [0, 1]  # after the last of the two rounds, not after each
    _sane(res, 2)


def test_sequential_runs_the_final_stage_once_per_bone(two_bones, monkeypatch):
    res, runs = _track(two_bones, monkeypatch, mode="sequential")
    assert sorted(runs) == [0, 1]
    _sane(res, 2)


def test_a_frame_keeps_the_stage_outcome_of_its_kept_registration(two_bones, monkeypatch):
    """The final stage's outcome in a frame's timing is that of the registration kept, not a sum
    over the frame's registrations (here the stage after both rounds, as before)."""
    import core.tracking.frame_step as fs

    monkeypatch.setattr(fs, "FINAL_EVERY_ROUND", True)
    res, runs = _track(two_bones, monkeypatch, mode="joint", rounds=2)
    assert sorted(runs) == [0, 0, 1, 1]
    for fr in res.results.values():
        if fr.frame == 1:
            assert fr.timing["likelihood_taken"] in (0, 1)
            assert np.isfinite(fr.timing["likelihood_move_mm"])


def test_stage_move_check():
    """A final-stage move far beyond the bone's recent ones flags the frame "uncertain"; not before
    the bone has enough good frames, not for a move within the frame's own σ, not where the stage
    was not taken."""
    from core.tracking.frame_step import stage_move_check

    moves = [0.01, 0.02, 0.015, 0.012, 0.018]
    far = {"likelihood_taken": 1, "likelihood_move_mm": 0.1}
    got = stage_move_check(far, {"translation_mm": 0.12}, moves)
    assert len(got) == 1 and got[0].startswith("uncertain (the final stage moved the pose 0.100 mm")
    assert stage_move_check(far, None, moves) == got  # without a confidence: the move alone
    assert stage_move_check(far, {"translation_mm": 0.12}, moves[:4]) == []  # too few good frames
    assert stage_move_check(far, {"translation_mm": 0.25}, moves) == []  # within half the frame's σ
    assert stage_move_check({**far, "likelihood_taken": 0}, None, moves) == []  # the similarity's pose
    assert stage_move_check({"likelihood_taken": 1, "likelihood_move_mm": 0.05}, None, moves) == []  # < 4x
    assert stage_move_check(far, None, [*moves, 0.2, 0.2, 0.2, 0.2, 0.2, 0.2], n=10) == []  # recent ones


def test_bone_state_keeps_the_good_frames_stage_moves():
    from core.tracking.frame_state import _BoneState
    from core.tracking.results import FrameResult

    st = _BoneState()
    pose = np.eye(4)
    t = {"likelihood_taken": 1, "likelihood_move_mm": 0.02}
    st.add(0, FrameResult("b", 0, pose, 0.9, 1, 0.0, True, timing=t))
    st.add(1, FrameResult("b", 1, pose, 0.9, 1, 0.0, False, ("uncertain (test)",), timing=t))
    st.add(2, FrameResult("b", 2, pose, 0.9, 1, 0.0, True, timing={**t, "likelihood_taken": 0}))
    st.add(3, FrameResult("b", 3, pose, 0.9, 1, 0.0, True))
    assert st.moves == [0.02] and len(st.history) == 4


def _flagging_run(two_bones, monkeypatch):
    """Sequential tracking of frames 0, 1, 2 where every move after the bone's first good one flags
    (limit 1 of a single frame's move, no σ allowance; frame 2 is frame 0's image); per bone the
    final stage's runs as (start, result) poses."""
    import core.tracking.final_stage as fst
    import core.tracking.register_options as ro
    from core.tracking.register import RegistrationOptions
    from core.tracking.trial import TrackingOptions, track

    sc, models, r, frames = two_bones
    seen = {}
    real = fst.final_stage

    def kept(renderer, frame, res, **k):
        out = real(renderer, frame, res, **k)
        seen.setdefault(k["bone"], []).append((res.pose.copy(), out.pose.copy()))
        return out

    monkeypatch.setattr(fst, "final_stage", kept)
    # the moments' Gauss-Newton search at these coarse views too (the similarity poses this test's
    # frame 2 moves from more than frame 1: register_options.newton_step)
    monkeypatch.setattr(ro, "COARSE_NEWTON_MM", 100.0)
    skip = {m.name: {0: sc.poses(0)[k]} for k, m in enumerate(models)}
    reg = RegistrationOptions(bounds=(5.0, 5.0), sigma=(1.0, 1.0), search="newton", final_highpass_px=2.0)
    o = TrackingOptions(mode="sequential", verify_restarts=0, registration=reg, refine_likelihood=True,
                        stage_move_limit=1.0, stage_move_sigmas=0.0, stage_move_frames=1)
    res = track(r, models, lambda f: frames[f % 2], [0, 1, 2], keyframes=skip, skip=skip, options=o)
    return res, seen, models


def test_a_flagged_stage_move_is_rejected(two_bones, monkeypatch):
    """A frame whose stage move the check flags keeps the similarity's pose (the pose the stage
    started from) and says so; a frame it does not flag keeps the stage's pose (the flagged move
    not confirmed first: frame_step.STAGE_MOVE_CONFIRM off)."""
    import core.tracking.frame_step as fs

    monkeypatch.setattr(fs, "STAGE_MOVE_CONFIRM", False)
    res, seen, models = _flagging_run(two_bones, monkeypatch)
    nm = models[0].name
    f1, f2 = res.results[(nm, 1)], res.results[(nm, 2)]
    (_, st1), (sim2, st2) = seen[0][-2:]
    assert not f1.flags and f1.timing["likelihood_taken"] == 1 and np.array_equal(f1.pose, st1)
    assert f2.timing["likelihood_move_mm"] > f1.timing["likelihood_move_mm"]  # > 1x the median of [f1]
    assert len(f2.flags) == 1 and f2.flags[0].startswith("uncertain (the final stage moved the pose")
    assert "final stage rejected" in f2.flags[0]
    assert np.array_equal(f2.pose, sim2) and not np.array_equal(sim2, st2)
    assert f2.timing["likelihood_taken"] == 0 and f2.timing["likelihood_rejected"] == 1
    assert np.all(np.isfinite(f2.confidence["sigma"]))


def test_a_flagged_stage_move_confirmed_from_the_guess_is_kept(two_bones, monkeypatch):
    """With the confirmation (frame_step.STAGE_MOVE_CONFIRM, the default) the flagged move of frame 2
    is run again from the far side of the stage's pose (the similarity's pose mirrored through it); it
    lands on the stage's pose, so the frame keeps it, unflagged, with a note; a confirmation that
    cannot succeed (CONFIRM_FRACTION 0) leaves the flag and the rejection as before."""
    import core.tracking.final_stage as fst
    import core.tracking.frame_step as fs

    res, seen, models = _flagging_run(two_bones, monkeypatch)
    nm = models[0].name
    f2 = res.results[(nm, 2)]
    (sim2, st2), (far2, _) = seen[0][-2:]  # the stage from the similarity, then from the far side
    assert np.linalg.norm(far2[:3, 3] - st2[:3, 3]) > 0.5 * np.linalg.norm(sim2[:3, 3] - st2[:3, 3])
    assert not f2.flags and f2.converged and f2.timing["likelihood_taken"] == 1
    assert np.array_equal(f2.pose, st2) and not np.array_equal(st2, sim2)
    assert len(f2.notes) == 1 and f2.notes[0].startswith("final stage's move")
    monkeypatch.setattr(fst, "CONFIRM_FRACTION", 0.0)
    monkeypatch.setattr(fs, "CONFIRM_FLOOR_MM", 0.0)  # (and frame_step's translation floor)
    res, seen, models = _flagging_run(two_bones, monkeypatch)
    f2 = res.results[(nm, 2)]
    assert len(f2.flags) == 1 and "final stage rejected" in f2.flags[0] and not f2.notes
    assert f2.timing["likelihood_rejected"] == 1


def test_rejected_gives_back_the_similarity_result():
    from core.tracking.final_stage import LikelihoodFit, rejected
    from core.tracking.register import RegistrationResult

    def result(t, timing, fit=None):
        P = np.eye(4)
        P[:3, 3] = t
        return RegistrationResult(P, np.r_[t, 0, 0, 0], 0.5, np.array([0.5, 0.5]), 10, 2, 0.1, True, "tol",
                                  (), timing, fit)

    sim = result([1.0, 0, 0], {"total_s": 0.1})
    fit = LikelihoodFit.of(np.eye(6) * 0.01, x=np.zeros(6), chi2=1.0, covariance_independent=np.eye(6),
                           similarity=sim)
    staged = result([1.1, 0, 0], {"total_s": 0.2, "likelihood_taken": 1, "likelihood_move_mm": 0.1}, fit)
    back = rejected(staged)
    assert np.array_equal(back.pose, sim.pose) and np.array_equal(back.x, sim.x) and back.fit is fit
    assert back.timing == {"total_s": 0.2, "likelihood_taken": 0, "likelihood_move_mm": 0.1,
                           "likelihood_rejected": 1}
    assert rejected(back) is None  # not the stage's pose any more
    assert rejected(result([1.0, 0, 0], {"likelihood_taken": 1}, None)) is None  # no similarity kept


def test_stage_move_options():
    from core.tracking.options import STAGE_MOVE_FRAMES, STAGE_MOVE_LIMIT, STAGE_MOVE_SIGMAS, TrackingOptions

    o = TrackingOptions()
    assert (o.stage_move_limit, o.stage_move_sigmas, o.stage_move_frames, o.stage_move_reject) == (
        STAGE_MOVE_LIMIT, STAGE_MOVE_SIGMAS, STAGE_MOVE_FRAMES, True) == (4.0, 0.5, 5, True)
    n = TrackingOptions(stage_move_frames=5.0).stage_move_frames  # a whole float is kept as an integer
    assert n == 5 and type(n) is int
    for bad in ({"stage_move_limit": 0.5}, {"stage_move_limit": float("nan")}, {"stage_move_sigmas": -1.0},
                {"stage_move_frames": 0}, {"stage_move_frames": 2.5}, {"stage_move_frames": True},
                {"stage_move_reject": 1}):
        name = next(iter(bad))
        with pytest.raises(ValueError, match=name):
            TrackingOptions(**bad)


def test_sequential_stage_subtracts_the_neighbours(two_bones, monkeypatch):
    """Sequential tracking's final stage subtracts the bones already registered in the frame (at
    their registered poses) and the others at their guesses, as joint tracking's does; the
    similarity's search gets no neighbours, as before."""
    import core.tracking.final_stage as fst
    from core.tracking.register import RegistrationOptions
    from core.tracking.trial import TrackingOptions, track

    sc, models, r, frames = two_bones
    got = []
    real = fst.final_stage

    def seen(renderer, frame, res, **k):
        out = real(renderer, frame, res, **k)
        got.append((k["bone"], k["others"], fst._NEIGHBOURS.get(), out.pose.copy()))
        return out

    monkeypatch.setattr(fst, "final_stage", seen)
    skip = {m.name: {0: sc.poses(0)[k]} for k, m in enumerate(models)}
    reg = RegistrationOptions(bounds=(5.0, 5.0), sigma=(1.0, 1.0), search="newton", final_highpass_px=2.0)
    o = TrackingOptions(mode="sequential", verify_restarts=0, registration=reg, refine_likelihood=True)
    res = track(r, models, frames.__getitem__, [0, 1], keyframes=skip, skip=skip, options=o)
    assert [g[0] for g in got] == [0, 1] and all(g[1] is None for g in got)  # the search: none
    (_, _, n0, p0), (_, _, n1, _) = got
    assert list(n0[1]) == [1] and np.allclose(n0[0][0], sc.poses(0)[1])  # the calcaneus at its guess
    assert list(n1[1]) == [0] and np.array_equal(n1[0][0], p0)  # the talus as registered in the frame
    assert np.array_equal(res.results[(models[0].name, 1)].pose, p0)
    assert fst._NEIGHBOURS.get() is None
