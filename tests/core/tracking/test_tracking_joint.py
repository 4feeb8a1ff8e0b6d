"""Joint tracking's lockstep registrations (core.tracking.joint) and the tracker's closed-form pose
differences (core.tracking.checks), on ideal 128² views of the talus and calcaneus (CPU device)."""

from __future__ import annotations

import numpy as np
import pytest

from core.geometry.transforms import params_from_pose, pose_from_params


@pytest.fixture(scope="module")
def two_bones(talus_calcaneus_128):
    from core.tracking.cost import prepare_frame

    sc, models, r, frames = talus_calcaneus_128
    return sc, models, r, prepare_frame(frames[1])


def test_lockstep_registrations_are_those_of_register(two_bones):
    """Each bone's lockstep search ends where register() ends from the same start, neighbour
    subtracted at the same pose: the same pose, score, steps and fit."""
    from core.tracking.joint import JointJob, lockstep_applies, register_together
    from core.tracking.register import RegistrationOptions, register

    sc, models, r, frame = two_bones
    o = RegistrationOptions(bounds=(5.0, 5.0), sigma=(1.0, 1.0), search="newton")
    assert lockstep_applies(o) and not lockstep_applies(RegistrationOptions(search="local"))
    truth = sc.poses(1)
    offs = [np.r_[0.6, -0.4, 0.3, np.radians([0.8, -0.5, 0.6])],
            np.r_[-0.5, 0.3, 0.4, np.radians([-0.6, 0.7, 0.4])]]
    starts = [pose_from_params(d, center=m.centroid, base=truth[k]) for k, (d, m) in
              enumerate(zip(offs, models, strict=True))]
    jobs = [JointJob(k, starts[k], m.centroid, m.outline, (truth[[1 - k]], [1 - k]))
            for k, m in enumerate(models)]
    together = register_together(r, frame, jobs, o)
    for k, (m, job) in enumerate(zip(models, jobs, strict=True)):
        alone = register(r, frame, bone=k, initial_pose=job.initial_pose, center=m.centroid, options=o,
                         others=job.others, outline=m.outline)
        t = together[k]
        assert t.converged == alone.converged and t.reason == alone.reason
        assert t.evaluations == alone.evaluations and t.generations == alone.generations
        np.testing.assert_allclose(t.pose, alone.pose, atol=1e-9)
        np.testing.assert_allclose(t.score, alone.score, atol=1e-9)
        np.testing.assert_allclose(t.fit.H, alone.fit.H, rtol=1e-9, atol=1e-12)
        e = params_from_pose(t.pose, center=m.centroid, base=truth[k])
        assert np.linalg.norm(e[:3]) < 0.3 and np.degrees(np.linalg.norm(e[3:])) < 0.6, e
        assert t.timing["engine_steps_x1"] == alone.timing["engine_steps_x1"] > 0


def test_lockstep_joint_tracking_is_as_accurate(two_bones):
    """Joint tracking with the Gauss-Newton search, lockstep and one bone after another: both
    within the same small error of the truth."""
    from dataclasses import replace

    from core.tracking.register import RegistrationOptions
    from core.tracking.trial import TrackingOptions, track

    sc, models, r, _ = two_bones
    frames = {i: [m.to_float(f) for m, f in zip(sc.imaging, sc.render_frame(i), strict=True)] for i in (0, 1)}
    skip = {m.name: {0: sc.poses(0)[k]} for k, m in enumerate(models)}
    reg = RegistrationOptions(bounds=(5.0, 5.0), sigma=(1.0, 1.0), search="newton")
    base = TrackingOptions(mode="joint", confidence=False, verify_restarts=0, registration=reg)
    err = {}
    for lock in (True, False):
        res = track(r, models, frames.__getitem__, [0, 1], keyframes=skip, skip=skip,
                    options=replace(base, lockstep=lock))
        assert res.summary()["converged_fraction"] == 1.0
        for k, m in enumerate(models):
            e = params_from_pose(res.results[(m.name, 1)].pose, center=m.centroid, base=sc.poses(1)[k])
            err[lock, k] = (np.linalg.norm(e[:3]), np.degrees(np.linalg.norm(e[3:])))
    for k in range(2):
        assert err[True, k][0] < 0.3 and err[True, k][1] < 0.6, err
        assert err[True, k][0] < err[False, k][0] + 0.05 and err[True, k][1] < err[False, k][1] + 0.1, err


def test_closed_form_pose_differences_are_the_transforms():
    from core.tracking.checks import pose_delta, same_optimum, step_pose

    g = np.random.default_rng(3)
    c = g.normal(size=3) * 20
    for angle in (0.0, 1e-7, 1e-3, 0.3, 2.0, 3.1):
        a = pose_from_params(np.r_[g.normal(size=3) * 5, g.normal(size=3)], center=c)
        p = np.r_[g.normal(size=3), g.normal(size=3)]
        p[3:] *= angle / np.linalg.norm(p[3:])
        b = pose_from_params(p, center=c, base=a)
        np.testing.assert_allclose(pose_delta(a, b, c), params_from_pose(b, center=c, base=a), atol=1e-9)
        np.testing.assert_allclose(step_pose(p, a, c), b, atol=1e-9)
    b = pose_from_params(np.r_[0.4, 0, 0, np.radians([0.3, 0, 0])], center=c, base=a)
    assert same_optimum(a, b, c)
    assert not same_optimum(a, pose_from_params(np.r_[0, 0, 0, np.radians([0.6, 0, 0])], center=c, base=a), c)


def test_fallback_goes_on_from_the_steps_taken(two_bones):
    """register(..., tried=(full-resolution stage, engine, s)) goes on with the half-resolution
    fallback: the registration of register() from the same start, without repeating its first
    stage (register_together's lanes that did not converge)."""
    from core.tracking.engine import engine_cost
    from core.tracking.register import RegistrationOptions, register

    sc, models, r, frame = two_bones
    o = RegistrationOptions(bounds=(10.0, 10.0), sigma=(1.0, 1.0), search="newton")
    m = models[0]
    start = pose_from_params(np.r_[4.0, -3.5, 3.0, np.radians([5.0, -4.0, 4.5])], center=m.centroid,
                             base=sc.poses(1)[0])
    alone = register(r, frame, bone=0, initial_pose=start, center=m.centroid, options=o, outline=m.outline)
    assert len(alone.stages) == 3 and not alone.stages[0].converged  # full, then half and full resolution
    c = engine_cost(r, bone=0, views=(0, 1), scale=1.0, term=o.terms[0])
    went_on = register(r, frame, bone=0, initial_pose=start, center=m.centroid, options=o, outline=m.outline,
                       tried=(alone.stages[0], c, 0.5))
    np.testing.assert_allclose(went_on.pose, alone.pose, atol=1e-9)
    assert went_on.evaluations == alone.evaluations and went_on.reason == alone.reason
    assert went_on.time_s >= 0.5
