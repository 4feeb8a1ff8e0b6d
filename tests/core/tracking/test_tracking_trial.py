from dataclasses import replace

import numpy as np
import pytest

from core.geometry.transforms import params_from_pose, pose_from_params
from core.tracking.register import Level, RegistrationOptions
from core.tracking.trial import TrackingOptions, predict_pose, track

FAST = TrackingOptions(registration=RegistrationOptions(
    bounds=(4.0, 4.0), levels=(Level(1.0, "cmaes", (0.7, 0.7), popsize=10, max_generations=40, tol_x=0.02),),
    refine="pattern"), confidence=False)
# FAST without the first frame's verifying restarts (its search, not their check, is what the tests of
# the frame loop below need): they took 3,300-3,900 of a 5-frame run's 5,000-12,000 evaluations
QUICK = replace(FAST, verify_restarts=0)


def _err(P, T, c):
    e = params_from_pose(P, center=c, base=T)
    return np.linalg.norm(e[:3]), np.degrees(np.linalg.norm(e[3:]))


def test_predict_pose_rules():
    c = np.array([1.0, 2.0, 3.0])
    step = np.r_[0.5, -0.2, 0.1, 0.01, 0.02, -0.01]
    T0 = np.eye(4)
    T1 = pose_from_params(step, center=c, base=T0)
    T2 = pose_from_params(step, center=c, base=T1)
    hist = [(0, T0), (1, T1)]
    np.testing.assert_allclose(predict_pose(hist, 2, c, guess="velocity"), T2, atol=1e-9)
    np.testing.assert_allclose(predict_pose(hist, 2, c, guess="previous"), T1)
    np.testing.assert_allclose(predict_pose([], 5, c, keyframes={0: T0, 9: T1}), T1)  # nearest keyframe
    kf = {0: T0, 10: T1, 20: T2}
    np.testing.assert_allclose(predict_pose(hist, 10, c, guess="spline", keyframes=kf), T1, atol=1e-9)
    mid = predict_pose(hist, 5, c, guess="spline", keyframes=kf)
    assert np.isclose(params_from_pose(mid, center=c, base=T0)[0], 0.25, atol=0.02)
    with pytest.raises(ValueError, match="keyframes"):
        predict_pose([], 0, c)
    with pytest.raises(ValueError, match="guess"):
        TrackingOptions(guess="psychic")


def test_track_forward_records_each_frame_and_is_accurate(walking_talus_64):
    """64² views, frame 0's search from the hand-placed start with the frames' options (measured
    errors 0.002-0.006 mm, 0.005-0.018 deg; 2.1 s of CPU, against 10-11 s at 128² with the widened,
    verified first-frame search)."""
    w = walking_talus_64
    sc, c = w["scene"], w["model"].centroid
    start = pose_from_params(np.r_[1.5, -1.0, 1.0, 0.02, -0.02, 0.01], center=c, base=sc.poses(0)[0])
    recs, prog = [], []
    res = track(w["renderer"], [w["model"]], w["frames"], range(5), keyframes={"talus": {0: start}},
                options=replace(QUICK, first=QUICK.registration), record=lambda *a: recs.append(a),
                progress=lambda d, n, fr: prog.append((d, n)))
    assert [r[1] for r in recs] == [0, 1, 2, 3, 4] and prog[-1] == (5, 5)
    assert res.status == "complete" and res.summary()["converged_fraction"] == 1.0
    P = res.poses("talus")
    for k in range(5):
        dt, dr = _err(P[k], sc.poses(k)[0], c)
        assert dt < 0.1 and dr < 0.2, (k, dt, dr)
        np.testing.assert_allclose(recs[k][2], P[k])


def test_track_backward_cancel_and_resume(walking_talus):
    w = walking_talus
    sc = w["scene"]
    kf = {"talus": {6: sc.poses(6)[0]}}
    journal = {}
    calls = []

    def cancel():
        calls.append(1)
        return len(journal) >= 2

    def record(b, f, P, s):
        journal[f] = P

    order = range(6, 2, -1)
    res = track(w["renderer"], [w["model"]], w["frames"], order, keyframes=kf, options=QUICK, record=record,
                cancel=cancel)
    assert res.status == "cancelled" and sorted(journal) == [5, 6]
    seen = []
    res2 = track(w["renderer"], [w["model"]], w["frames"], order, keyframes=kf, options=QUICK,
                 record=lambda b, f, P, s: seen.append(f), skip={"talus": dict(journal)})
    assert seen == [4, 3] and res2.status == "complete"
    c = w["model"].centroid
    dt, dr = _err(res2.poses("talus")[3], sc.poses(3)[0], c)
    assert dt < 0.1 and dr < 0.2


def test_bad_frames_are_flagged_and_tracking_goes_on(walking_talus_64):
    w = walking_talus_64
    sc = w["scene"]

    def frames(i):
        if i == 1:
            return [w["frames"](1)[0], None]  # view 1 lost this frame
        if i == 2:
            return w["frames"](40)  # the wrong images: the bone is elsewhere
        return w["frames"](i)

    recs = []
    res = track(w["renderer"], [w["model"]], frames, range(4), keyframes={"talus": {0: sc.poses(0)[0]}},
                options=QUICK, record=lambda *a: recs.append(a[1]))
    r1, r2, r3 = (res.results[("talus", k)] for k in (1, 2, 3))
    assert r1.pose is None and "missing in view 2" in r1.flags[0]  # views counted from 1
    assert r2.retried and r2.flags and not r2.converged
    assert r3.converged and not r3.flags  # the flagged frame did not spoil the next guess
    assert 1 not in recs and 3 in recs
    assert {r.frame for r in res.flagged} == {1, 2}
    far = {"talus": {0: sc.poses(0)[0] @ np.diag([1, 1, 1, 1.0])}}
    far["talus"][0] = far["talus"][0].copy()
    far["talus"][0][:3, 3] += [0, 0, 3000.0]
    res = track(w["renderer"], [w["model"]], w["frames"], [0], keyframes=far, options=QUICK)
    assert "outside the field of view" in res.results[("talus", 0)].flags[0]


def test_a_score_drop_of_the_image_is_confirmed_not_flagged(walking_talus):
    """Frame 2 of the right pose in noisier images (2 % multiplicative noise) scores below 0.85 x
    the median of the frames before: the wider retries and the restart end at the same pose, so
    the drop is the image's — noted, not flagged (the wrong images of the test above stay flagged).
    The tracker's own registration options (a local search; its retries' global CMA-ES stage)
    and one restart: the confirmation needs one, and the CMA-ES levels of FAST cost twice the CPU."""
    from core.tracking.trial import FrameResult

    w = walking_talus
    sc = w["scene"]

    def frames(i):
        imgs = w["frames"](i)
        if i != 2:
            return imgs
        g = np.random.default_rng(5)
        return [(im * (1 + 0.02 * g.standard_normal(im.shape))).astype(np.float32) for im in imgs]

    done = {f: FrameResult("talus", f, sc.poses(f)[0], 1.0, 1, 0.0, True) for f in (0, 1)}
    o = TrackingOptions(confidence=False, verify_restarts=1)
    res = track(w["renderer"], [w["model"]], frames, [0, 1, 2], keyframes={"talus": {0: sc.poses(0)[0]}},
                skip={"talus": done}, options=o)
    fr = res.results[("talus", 2)]
    assert fr.retried and not fr.flags and fr.converged, fr.flags
    assert fr.score < 0.85 and "confirmed the optimum" in fr.notes[0], fr.notes
    dt, dr = _err(fr.pose, sc.poses(2)[0], w["model"].centroid)
    assert dt < 0.3 and dr < 1.2, (dt, dr)  # measured 0.18 mm, 0.70 deg (the noise's)


def test_confidence_is_reported(walking_talus):
    w = walking_talus
    sc = w["scene"]
    o = TrackingOptions(registration=FAST.registration, confidence=True, verify_restarts=0)
    res = track(w["renderer"], [w["model"]], w["frames"], [0], keyframes={"talus": {0: sc.poses(0)[0]}},
                options=o)
    conf = res.results[("talus", 0)].confidence
    assert conf["method"] == "curvature" and len(conf["sigma"]) == 6
    assert all(s is not None and 0 < s < 1.0 for s in conf["sigma"])


def test_uncertain_frames_are_flagged_when_asked(walking_talus):
    w = walking_talus
    sc = w["scene"]
    kf = {"talus": {0: sc.poses(0)[0]}}
    base = TrackingOptions(registration=FAST.registration, confidence=True)
    plain = track(w["renderer"], [w["model"]], w["frames"], [0, 1], keyframes=kf, skip=kf, options=base)
    conf = plain.results[("talus", 1)].confidence
    assert not plain.results[("talus", 1)].flags
    from dataclasses import replace

    tight = replace(base, max_uncertainty=(0.5 * conf["translation_mm"], 1e3))
    res = track(w["renderer"], [w["model"]], w["frames"], [0, 1], keyframes=kf, skip=kf, options=tight)
    fr = res.results[("talus", 1)]
    assert fr.pose is not None and not fr.converged  # recorded, sent for review
    assert any(f.startswith("uncertain (confidence") for f in fr.flags), fr.flags
    loose = replace(base, max_uncertainty=(2 * conf["translation_mm"], 2 * conf["rotation_deg"]))
    ok = track(w["renderer"], [w["model"]], w["frames"], [0, 1], keyframes=kf, skip=kf, options=loose)
    assert not ok.results[("talus", 1)].flags
    for bad in ((0.0, 1.0), (1.0,), (1.0, float("nan"))):
        with pytest.raises(ValueError, match="max_uncertainty"):
            TrackingOptions(max_uncertainty=bad)
    with pytest.raises(ValueError, match="confidence"):
        TrackingOptions(max_uncertainty=(1.0, 1.0), confidence=False)


def test_filtered_poses_reduce_independent_noise_and_skip_flagged_frames():
    from core.tracking.trial import FrameResult, TrackingResult

    g = np.random.default_rng(3)
    c = np.array([5.0, -3.0, 10.0])
    n, fs = 120, 250.0
    t = np.arange(n) / fs
    truth = [pose_from_params(np.r_[8 * np.sin(2 * np.pi * 2 * t[k]), 3 * t[k], 0.0,
                                    np.radians(10) * np.sin(2 * np.pi * 1.5 * t[k]), 0.0, 0.0],
                              center=c, base=np.eye(4)) for k in range(n)]
    noisy = [pose_from_params(np.r_[g.normal(size=3) * 0.1, np.radians(g.normal(size=3) * 0.3)], center=c,
                              base=T) for T in truth]
    results = {("b", k): FrameResult("b", k, noisy[k], 0.9, 1, 0.0, True) for k in range(n)}
    results[("b", 40)] = FrameResult("b", 40, noisy[40] @ np.diag([1, 1, 1, 1.0]), 0.2, 1, 0.0, False,
                                     ("score drop",))
    res = TrackingResult(("b",), tuple(range(n)), results, "complete", 1.0)
    F, fc = res.filtered_poses("b", fs, center=c)
    assert 3.0 < fc < 0.2 * fs
    assert np.all(np.isnan(F[40])) and np.all(np.isfinite(F[39]))
    raw = np.array([_err(noisy[k], truth[k], c) for k in range(n) if k != 40])
    filt = np.array([_err(F[k], truth[k], c) for k in range(n) if k != 40])
    assert np.sqrt(np.mean(filt**2, axis=0)).max() < 0.6 * np.sqrt(np.mean(raw**2, axis=0)).min() or \
        np.all(np.sqrt(np.mean(filt**2, axis=0)) < 0.6 * np.sqrt(np.mean(raw**2, axis=0)))
    F2, fc2 = res.filtered_poses("b", fs, cutoff_hz=12.0, center=c)
    assert fc2 == 12.0 and F2.shape == (n, 4, 4)


def test_register_start_recovers_a_hand_placed_pose(talus_scene):
    from core.tracking.cost import prepare_frame
    from core.tracking.trial import register_start

    s = talus_scene
    sc, m = s["scene"], s["model"]
    truth = sc.poses(2)[0]
    start = pose_from_params(np.r_[2.0, -1.5, 1.0, np.radians([2.0, -2.0, 1.5])], center=m.centroid,
                             base=truth)
    o = TrackingOptions(first=FAST.registration, verify_restarts=2, confidence=False)
    fr = register_start(s["renderer"], prepare_frame(s["fluence"](2)), m, 0, start, options=o)
    dt, dr = _err(fr.pose, truth, m.centroid)
    assert fr.converged and not fr.flags and dt < 0.15 and dr < 0.3, (dt, dr, fr.flags)
    assert fr.evaluations > 0 and fr.frame == -1


def test_mean_tre_of_a_known_motion(talus_scene):
    from core.studies.tracking.acceptance import mean_tre

    m = talus_scene["model"]
    T = np.eye(4)
    S = T.copy()
    S[:3, 3] = [0.3, 0.0, 0.4]
    assert np.isclose(mean_tre(m, S, T), 0.5)
    R = pose_from_params(np.r_[0, 0, 0, np.radians(2.0), 0, 0], center=m.centroid, base=T)
    tre = mean_tre(m, R, T)
    assert 0.0 < tre < np.radians(2.0) * 40  # points within 40 mm of the centroid


def test_benchmark_smoke_reports_one_bone_with_breakdown():
    from core.studies.tracking.benchmark import run

    res = run(quick=True, device="cpu", frames=2, pixels=64, cases="one", repeats=2)
    assert "three_bones" not in res and res["mode"] == "joint"
    assert res["joint_rounds"] == 1 and res["one_bone"]["final"] == "none"  # what the case ran
    ee = res["one_bone"]["end_to_end"]
    assert len(ee["runs_wall_s"]) == 2 and ee["wall_s"] == pytest.approx(sum(ee["runs_wall_s"]) / 2)
    assert len(ee["gc_runs"]) == 2 and {"median_ms", "after_last_frame_ms"} <= set(ee["frame_clock"])
    assert ee["registration_ms_mean_after_first_frame"] > 0  # (a host pause: the mean and the longest frame)
    pb = ee["per_bone"]["talus"]
    assert pb["flagged"] == len(pb["flagged_frames"])
    if "bound_ratio" in pb:  # silent failures: over 4x the per-frame bound and not flagged
        assert pb["silent_failures"] == len(pb["silent_failure_frames"]) <= pb["over_4x_bound"] <= 2
    e = res["one_bone"]["profiled"]
    assert e["frames_per_second"] > 0 and set(e["breakdown_ms_per_frame"]) == {
        "drr", "metric_and_sync", "cost_host", "optimizer", "other"}
    with pytest.raises(ValueError, match="cases"):
        run(quick=True, device="cpu", frames=2, pixels=64, cases="four")
    with pytest.raises(ValueError, match="repeats"):
        run(quick=True, device="cpu", frames=2, pixels=64, cases="one", repeats=0)


def test_joint_tracking_of_two_overlapping_bones_counts_both_rounds():
    """Talus and calcaneus (overlapping in the views), each registered with the other's DRR
    subtracted; a frame's work adds up both rounds. 64² views: errors 0.002-0.009 mm, 0.008-0.014
    deg (128²: 0.002-0.008 mm, 0.003-0.016 deg), 4.7 s of CPU for both runs against 13.5 s."""
    from core.render import DRRRenderer
    from core.synthetic import make_foot_scene
    from core.tracking.bones import bone_model

    sc = make_foot_scene(n_frames=3, pixels=64, spacing=1.5, names=("talus", "calcaneus"), beads_per_bone=0,
                         phase=(0.0, 0.03),
                         soft_tissue=False, imaging="ideal", floor_thickness_mm=0)
    models = [bone_model(b, mesh=False) for b in sc.bones]
    r = DRRRenderer(sc.rig, [b.to_attenuation(sc.bone_transfer) for b in sc.bones], device="cpu")
    frames = {i: [m.to_float(f) for m, f in zip(sc.imaging, sc.render_frame(i), strict=True)]
              for i in range(3)}
    kf = {m.name: {0: sc.poses(0)[k]} for k, m in enumerate(models)}
    skip = {m.name: {0: sc.poses(0)[k]} for k, m in enumerate(models)}
    out = {}
    for rounds in (1, 2):
        o = replace(FAST, mode="joint", joint_rounds=rounds)
        out[rounds] = track(r, models, frames.__getitem__, [0, 1, 2], keyframes=kf, skip=skip, options=o)
    res = out[2]
    assert res.summary()["converged_fraction"] == 1.0
    for k, m in enumerate(models):
        for f in (1, 2):
            mm, deg = _err(res.results[(m.name, f)].pose, sc.poses(f)[k], m.centroid)
            assert mm < 0.5 and deg < 1.0, (m.name, f, mm, deg)
    # round one of both runs is the same search; the second round adds its work and time
    for key, one in out[1].results.items():
        if key[1] == 0:
            continue
        two = res.results[key]
        assert two.evaluations > one.evaluations
        assert two.timing["calls"] > one.timing["calls"]
