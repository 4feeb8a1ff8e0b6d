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
