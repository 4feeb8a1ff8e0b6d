"""The ``"newton"`` search's looser tolerance before a final stage
(:data:`core.tracking.register_options.STAGE_SEARCH_TOL`, :func:`~core.tracking.register_options.
before_stage`): one bone's registration and joint tracking's side-by-side searches stop there when a
stage follows, and at their own 0.02 without one (ideal 128² views, CPU; the stage itself replaced by
the identity: its own tests run it)."""

from __future__ import annotations

import numpy as np
import pytest

import core.tracking.register_options as ro
from core.geometry.transforms import pose_from_params
from core.tracking.cost import prepare_frame
from core.tracking.register import Level, RegistrationOptions, register


def test_before_stage_loosens_only_the_full_resolution_gauss_newton_level_before_a_stage(monkeypatch):
    gn = Level(scale=1.0, method="gauss_newton", sigma=(0.25, 0.5), max_generations=8, tol_x=0.02)
    staged = RegistrationOptions(search="newton", final="likelihood")
    assert ro.before_stage(gn, staged).tol_x == ro.STAGE_SEARCH_TOL == 0.5
    assert ro.before_stage(gn, RegistrationOptions(search="newton")) is gn  # no stage
    half = Level(scale=2.0, method="gauss_newton", sigma=(0.5, 1.0), tol_x=0.05)
    assert ro.before_stage(half, staged) is half  # not the full-resolution level
    quad = Level(scale=1.0, method="quadratic", sigma=(0.25, 0.5), tol_x=0.02)
    assert ro.before_stage(quad, staged) is quad
    monkeypatch.setattr(ro, "STAGE_SEARCH_TOL", None)
    assert ro.before_stage(gn, staged) is gn  # the search as without a stage


def _start(sc, frame: int, offset) -> np.ndarray:
    truth = sc["scene"].poses(frame)[0]
    off = np.asarray(offset, dtype=float)
    return pose_from_params(np.r_[off[:3], np.radians(off[3:])], center=sc["model"].centroid, base=truth)


@pytest.fixture
def recorded(monkeypatch):
    """The tol_x of every Levenberg–Marquardt search started (one bone's and side by side), with
    the final stage(s) the identity."""
    import core.tracking.engine_search as es
    import core.tracking.final_stage as fst
    import core.tracking.joint as joint

    tols: list = []
    plain = es.LevenbergMarquardt

    class Recording(plain):
        def __init__(self, *a, **k):
            super().__init__(*a, **k)
            tols.append(self.tol_x)

    monkeypatch.setattr(es, "LevenbergMarquardt", Recording)
    monkeypatch.setattr(joint, "LevenbergMarquardt", Recording)
    monkeypatch.setattr(fst, "final_stage", lambda renderer, frame, res, **kw: res)
    monkeypatch.setattr(fst, "final_stages", lambda renderer, frame, calls: [r for r, _ in calls])
    return tols


def test_one_bones_newton_search_stops_at_the_looser_tolerance_before_a_stage(talus_scene, recorded):
    sc = talus_scene
    m = sc["model"]
    frame = prepare_frame(sc["fluence"](1))
    start = _start(sc, 1, [0.6, -0.4, 0.3, 0.5, -0.8, 0.6])
    steps = {}
    for final in (None, "likelihood"):
        recorded.clear()
        o = RegistrationOptions(bounds=(5.0, 5.0), sigma=(1.0, 1.0), search="newton", final=final)
        res = register(sc["renderer"], frame, bone=0, initial_pose=start, center=m.centroid, options=o,
                       outline=m.outline)
        assert res.converged and recorded == [0.02 if final is None else 0.5]
        steps[final] = res.timing["engine_steps_x1"]
    assert 1 <= steps["likelihood"] <= steps[None]


def test_joint_side_by_side_searches_stop_at_the_looser_tolerance_before_a_stage(talus_calcaneus_128,
                                                                                  recorded):
    from core.tracking.joint import JointJob, register_together

    sc, models, r, frames = talus_calcaneus_128
    frame = prepare_frame(frames[1])
    jobs = lambda: [JointJob(k, sc.poses(1)[k], m.centroid, m.outline,  # noqa: E731
                             (sc.poses(1)[1 - k][None], [1 - k])) for k, m in enumerate(models)]
    for final, tol in ((None, 0.02), ("likelihood", 0.5)):
        recorded.clear()
        o = RegistrationOptions(bounds=(5.0, 5.0), sigma=(1.0, 1.0), search="newton", final=final)
        out = register_together(r, frame, jobs(), o)
        assert all(res.converged for res in out) and recorded == [tol, tol]


def test_stage_first_runs_the_stage_from_the_start_and_scores_its_pose(talus_scene, monkeypatch):
    """The study switch STAGE_FIRST: the stage from the initial pose, no search where its move is
    taken; the similarity scored once at the stage's pose (the real stage, ideal 128² views)."""
    import core.tracking.register as reg
    from core.studies.tracking.acceptance import pose_errors

    sc = talus_scene
    m = sc["model"]
    frame = prepare_frame(sc["fluence"](1))
    start = _start(sc, 1, [0.3, -0.2, 0.2, 0.3, -0.4, 0.3])
    o = RegistrationOptions(bounds=(5.0, 5.0), sigma=(1.0, 1.0), search="newton", final="likelihood")
    monkeypatch.setattr(reg, "STAGE_FIRST", True)
    res = register(sc["renderer"], frame, bone=0, initial_pose=start, center=m.centroid, options=o,
                   outline=m.outline)
    assert res.reason == "stage_first" and res.timing["likelihood_taken"] == 1 and res.converged
    assert res.timing["evaluations"] == 1 < res.evaluations  # the one score; the stage's poses besides
    e = pose_errors(res.pose, sc["scene"].poses(1)[0], m.centroid)
    assert np.linalg.norm(e[:3]) < 0.3 and np.linalg.norm(e[3:]) < 0.6, e
    monkeypatch.setattr(reg, "STAGE_FIRST", False)
    plain = register(sc["renderer"], frame, bone=0, initial_pose=start, center=m.centroid, options=o,
                     outline=m.outline)
    assert plain.reason != "stage_first" and plain.timing.get("engine_steps_x1", 0) >= 1
