"""core.tracking.stage_sigma: a flagged frame's σ with the final stage's move measured from the similarity's
optimum instead of where its search stopped (ideal 128² talus, Warp's CPU device; the similarity's search
on from the searched pose stubbed where a test places its optimum)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest


@pytest.fixture(scope="module")
def staged(talus_scene):
    """A registration of frame 2 with the likelihood stage, its move taken, and its frame and options."""
    from core.tracking.cost import prepare_frame
    from core.tracking.register import register
    from core.tracking.trial import TrackingOptions

    sc, model, r = talus_scene["scene"], talus_scene["model"], talus_scene["renderer"]
    frame = prepare_frame(talus_scene["fluence"](2))
    start = sc.poses(2)[0].copy()
    start[:3, 3] += (0.4, -0.3, 0.2)
    o = TrackingOptions(refine_likelihood=True, verify_restarts=0)
    res = register(r, frame, bone=0, initial_pose=start, center=model.centroid, options=o.registration)
    assert res.timing["likelihood_taken"] == 1
    return {"res": res, "frame": frame, "o": o, "model": model, "renderer": r}


def _rotated(P, center, deg):
    from core.geometry.transforms import pose_from_params

    return pose_from_params(np.r_[0, 0, 0, np.radians(deg)], center=center, base=P)


def test_the_move_is_the_stages_own(staged, monkeypatch):
    """The move from the similarity's pose in the stage's parameters is the one the stage took (its sizes in
    the timing) and the one its σ holds: with the similarity's optimum where the search stopped the σ is the
    same, and the sandwich left without the move is positive definite."""
    import core.tracking.register as register
    import core.tracking.stage_sigma as ss

    res, c = staged["res"], staged["model"].centroid
    sim = res.fit.similarity
    d = ss._move(res.pose, sim.pose, c)
    assert np.linalg.norm(d[:3]) == pytest.approx(res.timing["likelihood_move_mm"], rel=1e-6, abs=1e-9)
    assert np.linalg.norm(d[3:]) == pytest.approx(res.timing["likelihood_move_deg"], rel=1e-6, abs=1e-9)
    assert np.all(np.linalg.eigvalsh(res.fit.covariance - np.outer(d, d)) > 0)
    calls = []
    monkeypatch.setattr(register, "register", lambda *a, **k: calls.append(k) or sim)
    got, conv = ss.remeasured(staged["renderer"], staged["frame"], res, bone=0, center=c,
                              options=staged["o"].registration)
    assert conv is sim and calls[0]["options"].final is None and calls[0]["initial_pose"] is sim.pose
    np.testing.assert_allclose(got.fit.covariance, res.fit.covariance, rtol=1e-9, atol=1e-12)
    np.testing.assert_array_equal(got.pose, res.pose)
    assert got.fit.similarity is conv
    for k in ("likelihood_move_mm", "likelihood_move_deg"):  # (the move from the optimum: the same here)
        assert got.timing[k] == pytest.approx(res.timing[k], rel=1e-6, abs=1e-9)


def _stopped_short(staged, deg: float):
    """The staged result as if its search had stopped ``deg`` about x from the stage's pose (its σ with that
    move), and the sandwich."""
    from core.tracking.likelihood_model import LikelihoodFit
    from core.tracking.stage_sigma import _move

    res, c = staged["res"], staged["model"].centroid
    fit, sim = res.fit, res.fit.similarity
    S = fit.covariance - np.outer(*(2 * [_move(res.pose, sim.pose, c)]))
    far = replace(sim, pose=_rotated(res.pose, c, (-deg, 0, 0)))
    d = _move(res.pose, far.pose, c)
    new = LikelihoodFit.of(S + np.outer(d, d), x=fit.x, chi2=fit.chi2,
                           covariance_independent=fit.covariance_independent, similarity=far)
    t = {**res.timing, "likelihood_move_mm": float(np.linalg.norm(d[:3])),
         "likelihood_move_deg": float(np.linalg.norm(d[3:]))}
    return replace(res, fit=new, timing=t), far, S


def _checked(staged, res, S, monkeypatch, optimum, *, host_only=False):
    """register_checked of ``res`` (given as run), the bone's recent σ half the sandwich ``S``'s."""
    import core.tracking.attempt as at
    import core.tracking.register as register

    c = staged["model"].centroid
    sand = np.sqrt(np.diag(S))
    good = [(0.5 * float(np.linalg.norm(sand[:3])), 0.5 * float(np.linalg.norm(sand[3:])))] * 6
    monkeypatch.setattr(at, "_failures", lambda *a, **k: [])
    searched = []

    def search(*a, **k):
        searched.append(k)
        return replace(res.fit.similarity, pose=optimum, evaluations=26)

    monkeypatch.setattr(register, "register", search)
    a = at.register_checked(staged["renderer"], staged["frame"], staged["model"], 0, res.pose, res.pose,
                            staged["o"].registration, staged["o"], [], None, None, [], pre=(res, 0.0),
                            good_sigmas=good, host_only=host_only)
    return a, searched, c


def test_a_flag_from_where_the_search_stopped_is_remeasured(staged, monkeypatch):
    """The search stopped 2° about x from the stage's pose, the similarity's optimum 1e-5° from it (the
    ideal views' σ is about 0.001°): the σ from the optimum, not flagged, a note; the search's work
    counted; the pose and the stage's outcome kept, its move from the optimum."""
    res, far, S = _stopped_short(staged, 2.0)
    c = staged["model"].centroid
    d = np.sqrt(np.diag(S))
    assert np.linalg.norm(np.sqrt(np.diag(res.fit.covariance))[3:]) > 3 * 0.5 * np.linalg.norm(d[3:])
    near = _rotated(res.pose, c, (1e-5, 0, 0))
    a, searched, _ = _checked(staged, res, S, monkeypatch, near)
    assert len(searched) == 1 and searched[0]["options"].final is None
    np.testing.assert_array_equal(searched[0]["initial_pose"], far.pose)
    assert a.flags == [] and any("similarity's optimum" in n for n in a.notes)
    assert a.confidence["rotation_deg"] == pytest.approx(float(np.linalg.norm(d[3:])), rel=0.02)
    np.testing.assert_array_equal(a.result.pose, res.pose)
    np.testing.assert_array_equal(a.result.fit.similarity.pose, near)  # (a rejected move keeps the optimum)
    t = a.result.timing
    assert t["likelihood_taken"] == 1 and t["likelihood_move_deg"] == pytest.approx(1e-5, rel=1e-3)
    assert res.timing["likelihood_move_deg"] == pytest.approx(2.0, rel=1e-6)  # (the run's own, not changed)
    assert a.evaluations == res.evaluations + 26


def test_a_similarity_that_disagrees_stays_flagged(staged, monkeypatch):
    """The similarity's optimum as far as where the search stopped: still flagged (the costs disagree)."""
    res, far, S = _stopped_short(staged, 2.0)
    a, searched, _ = _checked(staged, res, S, monkeypatch, far.pose)
    assert searched and any(f.startswith("uncertain") for f in a.flags)


def test_host_only_leaves_it_to_the_full_checks_and_the_switch_off_flags(staged, monkeypatch):
    import core.tracking.stage_sigma as ss

    res, _, S = _stopped_short(staged, 2.0)
    near = _rotated(res.pose, staged["model"].centroid, (1e-5, 0, 0))
    a, searched, _ = _checked(staged, res, S, monkeypatch, near, host_only=True)
    assert a is None and not searched
    monkeypatch.setattr(ss, "REMEASURE", False)
    a, searched, _ = _checked(staged, res, S, monkeypatch, near)
    assert not searched and any(f.startswith("uncertain") for f in a.flags)


def test_a_search_cut_short_leaves_the_sigma(staged, monkeypatch):
    import core.tracking.register as register
    import core.tracking.stage_sigma as ss

    res = staged["res"]
    sim = res.fit.similarity
    cut = replace(sim, stages=(*sim.stages[:-1], replace(sim.stages[-1], reason="cancelled")))
    monkeypatch.setattr(register, "register", lambda *a, **k: cut)
    assert ss.remeasured(staged["renderer"], staged["frame"], res, bone=0, center=staged["model"].centroid,
                         options=staged["o"].registration) is None
