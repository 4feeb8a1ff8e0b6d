"""attempt.register_checked with a final stage: where the restart check finds a better optimum and keeps
its result (the restarts are searches only: joint.restarts_together runs no final stage), that result goes
through the final stage as every other registration the frame keeps — not a pose no stage refined, with the
earlier attempts' stage time in its timing and no stage outcome (ideal 128² talus, Warp's CPU device; the
restart check replaced by one whose better optimum is the search's pose without a stage, the wider search
from it by one that scores lower)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np


def test_a_restart_kept_goes_through_the_final_stage(talus_scene, monkeypatch):
    import core.tracking.attempt as at
    from core.tracking.cost import prepare_frame
    from core.tracking.likelihood_model import LikelihoodFit
    from core.tracking.register import register
    from core.tracking.trial import TrackingOptions
    from core.tracking.verify import StartCheck

    sc, model, r = talus_scene["scene"], talus_scene["model"], talus_scene["renderer"]
    frame = prepare_frame(talus_scene["fluence"](2))
    start = sc.poses(2)[0].copy()
    start[:3, 3] += (0.4, -0.3, 0.2)
    o = TrackingOptions(refine_likelihood=True, verify_restarts=2)
    opts = o.registration
    assert opts.final is not None
    search = register(r, frame, bone=0, initial_pose=start, center=model.centroid,
                      options=replace(opts, final=None))  # (the restarts' kind: no stage)
    assert "likelihood_taken" not in search.timing
    better = replace(search, score=search.score + 1.0)
    checked, wider = [], []

    def restarts(*a, **k):
        checked.append(k["result"])
        return StartCheck(better, True, False, (better.score,), ((0.0, 0.0),), 7)

    def wider_search(*a, **k):
        wider.append(k["options"].search)
        return replace(search, score=search.score - 1.0)  # (the restart stays the better)

    monkeypatch.setattr(at, "verify_start", restarts)
    monkeypatch.setattr(at, "register", wider_search)
    a = at.register_checked(r, frame, model, 0, start, start, opts, o, [], None, None, [], verify=True,
                            pre=(search, 0.0))
    assert checked and wider == ["global_newton"] and "start corrected by restarts" in a.notes
    t = a.result.timing
    assert t.get("likelihood_taken") in (0, 1)  # the stage ran on the kept restart
    if t["likelihood_taken"]:
        assert isinstance(a.result.fit, LikelihoodFit)
        np.testing.assert_array_equal(a.result.fit.similarity.pose, better.pose)
    stage = a.result.evaluations - better.evaluations
    assert stage > 0 and a.evaluations >= stage + 7  # (its renders counted, in the attempt's work too)
    assert a.timing["likelihood_s"] > 0
