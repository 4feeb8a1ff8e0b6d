"""Joint tracking's rounds after the first from each bone's prediction
(core.tracking.frame_step.RESTART_FROM_PREDICTION, opt-in; core.studies.tracking.joint_gap): the
starts and neighbours each round is given, and the poses against the truth, on ideal 128² views
of the talus and calcaneus (CPU device)."""

from __future__ import annotations

import numpy as np
import pytest


def _track(two, monkeypatch, *, restart: bool, lockstep: bool, option: bool = False):
    """Frame 1 tracked jointly (two rounds) from the true poses of frame 0; per round the bones'
    starts and the neighbours' poses given to their searches. ``restart`` sets the module switch,
    ``option`` ``TrackingOptions.joint_restart``."""
    import core.tracking.frame_step as fs
    from core.tracking.register import RegistrationOptions
    from core.tracking.trial import TrackingOptions, track

    sc, models, r, frames = two
    monkeypatch.setattr(fs, "RESTART_FROM_PREDICTION", restart)
    calls: list[dict] = []
    if lockstep:
        real = fs.register_together

        def spy(renderer, frame, jobs, options, **k):
            got = real(renderer, frame, jobs, options, **k)
            calls.append({j.bone: (np.array(j.initial_pose), np.array(j.others[0]), g.pose)
                          for j, g in zip(jobs, got, strict=True)})
            return got

        monkeypatch.setattr(fs, "register_together", spy)
    else:
        real = fs.register_checked

        def spy(renderer, frame, bone, i, start, *a, **k):
            got = real(renderer, frame, bone, i, start, *a, **k)
            others = a[4]
            if not calls or i in calls[-1]:
                calls.append({})
            calls[-1][i] = (np.array(start), np.array(others[0]), got.result.pose)
            return got

        monkeypatch.setattr(fs, "register_checked", spy)
    skip = {m.name: {0: sc.poses(0)[k]} for k, m in enumerate(models)}
    reg = RegistrationOptions(bounds=(5.0, 5.0), sigma=(1.0, 1.0), search="newton")
    o = TrackingOptions(mode="joint", joint_rounds=2, lockstep=lockstep, verify_restarts=0, registration=reg,
                        joint_restart=option)
    res = track(r, models, frames.__getitem__, [0, 1], keyframes=skip, skip=skip, options=o)
    return res, calls


@pytest.mark.parametrize(("lockstep", "restarts"), [(True, (False, True)), (False, (True,))],
                         ids=["lockstep", "one_by_one"])
def test_second_round_starts_from_the_prediction(talus_calcaneus_128, monkeypatch, lockstep, restarts):
    from core.studies.tracking.acceptance import pose_errors

    sc, models, _, _ = talus_calcaneus_128
    for restart in restarts:
        res, calls = _track(talus_calcaneus_128, monkeypatch, restart=restart, lockstep=lockstep)
        assert len(calls) == 2 and all(sorted(c) == [0, 1] for c in calls)
        first, second = calls
        for i in (0, 1):
            guess = sc.poses(0)[i]  # frame 0's pose: the prediction from one frame
            np.testing.assert_allclose(first[i][0], guess)
            start = second[i][0]
            if restart:  # round 1 from the prediction
                np.testing.assert_allclose(start, guess)
            else:  # from round 0's pose
                np.testing.assert_allclose(start, first[i][2])
                assert not np.allclose(start, guess)
            # the neighbour at its round-0 pose either way (one by one: the talus's round-1 pose
            # for the calcaneus, registered after it)
            near = second[0][2] if (i == 1 and not lockstep) else first[1 - i][2]
            np.testing.assert_allclose(second[i][1][0], near)
        for k, m in enumerate(models):
            fr = res.results[(m.name, 1)]
            assert fr.pose is not None and not fr.flags, fr
            e = pose_errors(fr.pose, sc.poses(1)[k], m.centroid)
            # ideal views: within 0.004-0.012 mm / 0.008-0.018 deg measured either way
            assert np.linalg.norm(e[:3]) < 0.05 and np.linalg.norm(e[3:]) < 0.1, (restart, m.name, e)


@pytest.mark.parametrize("lockstep", [True, False], ids=["lockstep", "one_by_one"])
def test_option_is_the_switch(talus_calcaneus_128, monkeypatch, lockstep):
    """``TrackingOptions.joint_restart`` starts the rounds where the module switch does: the same
    starts and bit-equal poses."""
    from core.tracking.trial import TrackingOptions

    switch, by_switch = _track(talus_calcaneus_128, monkeypatch, restart=True, lockstep=lockstep)
    monkeypatch.undo()  # the spies off (the second run's would call the first's)
    option, by_option = _track(talus_calcaneus_128, monkeypatch, restart=False, lockstep=lockstep,
                               option=True)
    assert len(by_switch) == 2
    for a, b in zip(by_switch, by_option, strict=True):
        assert sorted(a) == sorted(b)
        for i in a:
            for x, y in zip(a[i], b[i], strict=True):
                np.testing.assert_array_equal(x, y)
    assert switch.results.keys() == option.results.keys()
    for k, fr in switch.results.items():
        np.testing.assert_array_equal(fr.pose, option.results[k].pose)
        assert fr.flags == option.results[k].flags
    assert not TrackingOptions().joint_restart
    with pytest.raises(ValueError, match="joint_restart"):
        TrackingOptions(joint_restart=1)
