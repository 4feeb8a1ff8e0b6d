"""Joint registration's searches and final stages in one pipeline (core.tracking.joint_pipeline): the
same results to the bit as the stages run after every search (the switch off), on the ideal 128²
talus-calcaneus views (CPU device): a frame after a given one, jointly with the likelihood stage; a
search that falls back to half resolution too."""

from __future__ import annotations

import numpy as np


def _track(fixture, monkeypatch, on: bool):
    """Frame 1 tracked from frame 0's true poses, given (a later frame's lockstep round)."""
    import core.tracking.joint_pipeline as jp
    from core.tracking.register import RegistrationOptions
    from core.tracking.trial import TrackingOptions, track

    sc, models, r, imgs = fixture
    monkeypatch.setattr(jp, "PIPELINED_STAGES", on)
    keys = {m.name: {0: sc.poses(0)[k]} for k, m in enumerate(models)}
    reg = RegistrationOptions(bounds=(5.0, 5.0), sigma=(1.0, 1.0), search="newton")
    o = TrackingOptions(mode="joint", verify_restarts=0, registration=reg, refine_likelihood=True)
    return track(r, models, imgs.__getitem__, [0, 1], keyframes=keys, skip=keys, options=o)


def _same(a, b) -> None:
    assert a.results.keys() == b.results.keys()
    for key, x in a.results.items():
        y = b.results[key]
        np.testing.assert_array_equal(x.pose, y.pose)
        assert x.score == y.score or (np.isnan(x.score) and np.isnan(y.score))
        assert (x.flags, x.notes, x.evaluations, x.retried) == (y.flags, y.notes, y.evaluations, y.retried)
        assert x.confidence == y.confidence
        for k in ("likelihood_taken", "likelihood_steps", "likelihood_move_mm", "likelihood_move_deg"):
            assert (x.timing or {}).get(k) == (y.timing or {}).get(k)


def test_pipelined_stages_give_the_same_results(talus_calcaneus_128, monkeypatch):
    """Also the checks of a bone whose stage ended while the other's ran (frame_step's ``done``, host
    work only), taken by the frame's checks."""
    import core.tracking.frame_step as fs
    import core.tracking.joint_pipeline as jp

    used, early = [], []
    real, checked = jp.run_pipelined, fs.register_checked

    def spy(*a, **k):
        used.append(len(a[4]))
        return real(*a, **k)

    def spy_checks(*a, **k):
        got = checked(*a, **k)
        if k.get("host_only"):
            early.append(got is not None)
        return got

    monkeypatch.setattr(jp, "run_pipelined", spy)
    monkeypatch.setattr(fs, "register_checked", spy_checks)
    off = _track(talus_calcaneus_128, monkeypatch, False)
    assert not used and not early
    on = _track(talus_calcaneus_128, monkeypatch, True)
    assert used
    assert any(early)  # (a bone checked while the other's stage ran, its checks kept)
    assert all(r.timing.get("likelihood_taken") for r in on.results.values())
    _same(off, on)


def test_pipelined_fallback_to_half_resolution(talus_calcaneus_128, monkeypatch):
    """A bone whose full-resolution steps do not converge (one step allowed) goes on with the
    half-resolution fallback after the loop: the same results as before."""
    from dataclasses import replace

    import core.tracking.joint as joint
    import core.tracking.register as register

    real = joint.before_stage
    monkeypatch.setattr(joint, "before_stage", lambda lv, o: replace(real(lv, o), max_generations=1))
    tried = []
    plain = register.register

    def spy(*a, **k):
        tried.append(k.get("tried") is not None)
        return plain(*a, **k)

    monkeypatch.setattr(register, "register", spy)
    off = _track(talus_calcaneus_128, monkeypatch, False)
    n = sum(tried)
    on = _track(talus_calcaneus_128, monkeypatch, True)
    assert n > 0 and sum(tried) == 2 * n  # (the fallbacks, as many either way)
    _same(off, on)


def test_applies_tells_the_stages_by_identity(monkeypatch):
    """A study's wrapper of final_stages made with functools.wraps (the module's name and qualname copied)
    turns the pipeline off, as any wrapper does (it sees every call only without the pipeline), unless
    marked timing_only (it passes the calls on unchanged: frame_profile's), through every wrapper to the
    module's own function; a wrapped final_stage turns it off too."""
    import functools

    import core.tracking.final_stage as fst
    import core.tracking.joint_pipeline as jp

    jobs = [type("Job", (), {"bone": b})() for b in (0, 1)]
    own = fst.final_stages
    assert own is fst._PLAIN_FINAL_STAGES and jp.applies(jobs)
    assert not jp.applies(jobs + jobs[:1])  # (a bone twice)

    def wrap(f):
        @functools.wraps(f)
        def w(*a, **k):
            return f(*a, **k)
        return w

    plain = wrap(own)
    assert plain.__qualname__ == "final_stages" and plain.__module__ == fst.__name__
    monkeypatch.setattr(fst, "final_stages", plain)
    assert not jp.applies(jobs)
    monkeypatch.setattr(fst, "final_stages", jp.timing_only(wrap(own)))
    assert jp.applies(jobs)
    monkeypatch.setattr(fst, "final_stages", jp.timing_only(wrap(jp.timing_only(wrap(own)))))
    assert jp.applies(jobs)
    monkeypatch.setattr(fst, "final_stages", jp.timing_only(wrap(plain)))  # (a timing one around another)
    assert not jp.applies(jobs)
    monkeypatch.setattr(fst, "final_stages", own)
    monkeypatch.setattr(fst, "final_stage", jp.timing_only(wrap(fst.final_stage)))
    assert not jp.applies(jobs)  # (final_stage is called by final_stages: any wrapper of it sees every call)
