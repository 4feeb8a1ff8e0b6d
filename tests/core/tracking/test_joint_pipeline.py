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


def test_the_pipeline_after_the_searched_pose_switch_was_used(talus_calcaneus_128, monkeypatch):
    """joint_stage installs its switch's wrapper of final_stages once for the process; outside the switch
    the wrapper passes the calls on unchanged, so the pipeline applies there as before the switch was first
    used (it stayed off for the rest of the process), and not inside the switch."""
    import core.tracking.final_stage as fst
    import core.tracking.joint_pipeline as jp
    from core.tracking.joint_stage import searched_stages

    monkeypatch.setattr(fst, "final_stages", fst.final_stages)  # (the switch's wrapper taken off after)
    used = []
    real = jp.run_pipelined
    monkeypatch.setattr(jp, "run_pipelined", lambda *a, **k: used.append(1) or real(*a, **k))
    jobs = [type("Job", (), {"bone": b})() for b in (0, 1)]
    with searched_stages(True):
        assert fst.final_stages._searched_switch and not jp.applies(jobs)
    assert jp.applies(jobs)  # the switch off: its wrapper is the module's own final_stages
    _track(talus_calcaneus_128, monkeypatch, True)
    assert used
