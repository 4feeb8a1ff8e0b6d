"""The likelihood final stage with fewer steps (engine_likelihood.STOP_PRED: a refinement ends after a
step the data barely resolve, taken without rendering it; final_stage.ROBUST_FROM_LAST: the robust
round from the first refinement's last design, no step of its own) on Warp's CPU device: fewer steps,
poses and σ close to the converged stage's, and bones side by side as each alone, to the bit."""

from __future__ import annotations

import numpy as np
import pytest

from tests.core.tracking.test_likelihood_fast_kernels import noisy_talus  # noqa: F401 (a fixture)


def _fewer(monkeypatch, stop: float = 4.0, last: bool = True) -> None:
    """The fewer steps (the defaults) or, ``stop`` 0 and ``last`` False, the stage as first measured."""
    import core.tracking.engine_likelihood as el
    import core.tracking.final_stage as fst

    monkeypatch.setattr(el, "STOP_PRED", stop)
    monkeypatch.setattr(fst, "ROBUST_FROM_LAST", last)


@pytest.mark.parametrize("frame", [1, 3])
def test_fewer_steps_near_the_converged_stage(noisy_talus, monkeypatch, frame):  # noqa: F811
    """Measured (128², 1.5 mm, 4 px, frames 1-3): 6-8 steps → 2-3, poses within 4e-3 σ and σ within
    6e-3 relative of the converged stage's (256², 1 mm, frames 1-2: 0.045 σ, 0.019)."""
    from core.tracking.register import RegistrationOptions, register

    sc, model, r = noisy_talus["scene"], noisy_talus["model"], noisy_talus["renderer"]
    truth = sc.poses(frame)[0]
    fr = noisy_talus["frame"](frame)
    o = RegistrationOptions(bounds=(3.0, 3.0), search="newton", final="likelihood", final_highpass_px=4.0)
    out = []
    for fewer in (False, True):
        _fewer(monkeypatch, 4.0 if fewer else 0.0, fewer)
        res = register(r, fr, bone=0, initial_pose=truth, center=model.centroid, options=o)
        assert res.timing["likelihood_taken"] == 1
        out.append((np.asarray(res.x, float), np.sqrt(np.diag(res.fit.covariance)),
                    res.timing["likelihood_steps"], res.timing["likelihood_renders"]))
    (x0, s0, n0, r0), (x1, s1, n1, r1) = out
    assert np.all(np.isfinite(s0)) and np.all(s0 > 0)
    assert n1 <= 3 < n0
    assert r0 == n0 - 1 and r1 < n1  # (the robust refinement's first step takes the images before it)
    assert np.max(np.abs(x1 - x0) / s0) < 2e-2
    assert np.max(np.abs(s1 - s0) / s0) < 2e-2


def test_chord_steps_render_the_centre_alone(noisy_talus, monkeypatch):  # noqa: F811
    """engine_likelihood.CHORD_STEPS (opt-in): a refinement's later steps render one pose, the
    differences the first design's; the stage's poses stay within a fraction of σ (measured 0.09-0.18 σ
    at 256², 1 mm, with the fewer steps)."""
    import core.tracking.engine_likelihood as el
    from core.tracking.register import RegistrationOptions, register

    sc, model, r = noisy_talus["scene"], noisy_talus["model"], noisy_talus["renderer"]
    truth = sc.poses(2)[0]
    fr = noisy_talus["frame"](2)
    o = RegistrationOptions(bounds=(3.0, 3.0), search="newton", final="likelihood", final_highpass_px=4.0)
    _fewer(monkeypatch, 0.0, False)  # (refinements of several steps)
    out = []
    for chord in (False, True):
        monkeypatch.setattr(el, "CHORD_STEPS", chord)
        res = register(r, fr, bone=0, initial_pose=truth, center=model.centroid, options=o)
        assert res.timing["likelihood_taken"] == 1
        out.append((np.asarray(res.x, float), np.sqrt(np.diag(res.fit.covariance)), res.evaluations))
    (x0, s0, e0), (x1, _, e1) = out
    assert e1 < e0  # (a centre-only step renders one pose instead of 13)
    assert np.max(np.abs(x1 - x0) / s0) < 0.3
