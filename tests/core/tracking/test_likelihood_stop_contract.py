"""The likelihood stage's stop below STOP_PRED needing a contracted step (opt-in
engine_likelihood.STOP_CONTRACT): a refinement whose steps do not shrink fast goes on, so it ends
nearer the converged stage's pose (on the calcaneus of held-out seed 4 the stop left it up to
0.07 mm short along lab x; core.studies.tracking.stage_residue), on Warp's CPU device."""

from __future__ import annotations

import numpy as np

from core.geometry.transforms import pose_from_params
from tests.core.tracking.test_likelihood_fast_kernels import noisy_talus  # noqa: F401 (a fixture)


def test_a_stop_below_stop_pred_needs_a_contracted_step(noisy_talus, monkeypatch):  # noqa: F811
    """Every step below STOP_PRED (set huge): STOP_PRED alone ends each refinement at its first
    step; with STOP_CONTRACT the first refinement goes on to a step that shrank (its first has no
    step before it), the robust round after it may stop at once, and the pose is nearer the
    converged stage's (STOP_PRED 0, to tol)."""
    import core.tracking.engine_likelihood as el
    from core.tracking.final_stage import final_stage
    from core.tracking.register import RegistrationOptions, register

    sc, model, r = noisy_talus["scene"], noisy_talus["model"], noisy_talus["renderer"]
    truth = sc.poses(1)[0]
    fr = noisy_talus["frame"](1)
    start = pose_from_params(np.r_[0.3, -0.2, 0.2, np.radians([0.3, -0.2, 0.25])], center=model.centroid,
                             base=truth)
    o = RegistrationOptions(bounds=(3.0, 3.0), search="newton", final="likelihood", final_highpass_px=4.0)
    sim = register(r, fr, bone=0, initial_pose=start, center=model.centroid,
                   options=RegistrationOptions(bounds=(3.0, 3.0), search="newton"))

    out = {}
    for label, stop, contract in (("alone", 1e9, None), ("contract", 1e9, 0.1), ("converged", 0.0, None)):
        monkeypatch.setattr(el, "STOP_PRED", stop)
        monkeypatch.setattr(el, "STOP_CONTRACT", contract)
        res = final_stage(r, fr, sim, bone=0, initial_pose=start, center=model.centroid, options=o,
                          views=(0, 1))
        assert res.timing["likelihood_taken"] == 1
        out[label] = (np.asarray(res.x, float), res.timing["likelihood_steps"])
    (xa, na), (xc, nc), (x0, n0) = out["alone"], out["contract"], out["converged"]
    assert na == 2 < nc <= n0  # one step each refinement; more with the contraction asked
    assert np.linalg.norm(xc - x0) < np.linalg.norm(xa - x0)
