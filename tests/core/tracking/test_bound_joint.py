"""The joint Cramér–Rao bound of several bones (:func:`core.tracking.bound.joint_bound`): equal to
the per-bone bound where the projections do not overlap, above it where they do, and the spread of a
joint maximum-likelihood fit of both bones on Poisson frames."""

import numpy as np
import pytest

from core.geometry.transforms import pose_from_params
from core.studies.tracking.acceptance import pose_errors
from core.tracking.bound import joint_bound, pose_bound
from core.tracking.cost import OutsideViewError, search_roi


def _ramp(shape):
    """Tissue line integral in front of the bones: 1 to 3 across the image (photon weights differ)."""
    h, w = shape
    return np.broadcast_to(1.0 + 2.0 * np.arange(w) / (w - 1), (h, w)).copy()


@pytest.fixture(scope="module")
def pair():
    """The talus and the calcaneus of an ideal 96² biplane scene, 1.5 mm voxels, a CPU renderer."""
    from core.render import DRRRenderer
    from core.synthetic import make_foot_scene
    from core.tracking.bones import bone_model

    sc = make_foot_scene(n_frames=1, pixels=96, spacing=1.5, names=("talus", "calcaneus"), beads_per_bone=0,
                         phase=(0.0, 0.01), soft_tissue=False, imaging="ideal", floor_thickness_mm=0)
    r = DRRRenderer(sc.rig, [b.to_attenuation(sc.bone_transfer) for b in sc.bones], device="cpu")
    centers = np.array([bone_model(b, mesh=False).centroid for b in sc.bones])
    return r, sc.poses(0), centers


def _psd(A, scale):
    return np.linalg.eigvalsh(0.5 * (A + A.T)).min() > -1e-9 * scale


def test_bones_that_never_overlap_have_their_own_bound(pair):
    r, P, c = pair
    P = P.copy()
    P[1, :3, 3] += (0.0, -60.0, 0.0)  # the calcaneus moved off the talus in both views, still seen in both
    for v in range(2):
        assert search_roi(r, P[1], 1, views=[v], center=c[1], reach_mm=0.0, margin_px=6)[0][2] > 20
    L = [_ramp(cam.image_shape) for cam in r.cameras]
    jb = joint_bound(r, [0, 1], P, c, line_integral=L, quanta_per_pixel=3000.0)
    assert jb.bones == (0, 1) and jb.missing == () and jb.information.shape == (12, 12)
    assert np.all(jb.information[:6, 6:] == 0)  # no pixel where both projections change
    for k in range(2):
        own = pose_bound(r, k, P[k], c[k], line_integral=L, quanta_per_pixel=3000.0)
        np.testing.assert_allclose(jb.known[k].information, own.information, rtol=1e-12, atol=0)
        np.testing.assert_allclose(jb.joint[k].covariance, own.covariance, rtol=1e-9)
        assert jb.joint[k].rms_mm == pytest.approx(own.rms_mm, rel=1e-9)
        assert jb.joint[k].rms_deg == pytest.approx(own.rms_deg, rel=1e-9)
        assert jb.joint[k].pixels == own.pixels
    np.testing.assert_allclose(jb.ratio(), 1.0, rtol=1e-9)


def test_overlapping_bones_raise_the_bound_and_missing_bones_are_left_out(pair):
    r, P, c = pair
    L = [_ramp(cam.image_shape) for cam in r.cameras]
    jb = joint_bound(r, [0, 1], P, c, line_integral=L, quanta_per_pixel=3000.0)
    assert np.abs(jb.information[:6, 6:]).max() > 0  # the talus and calcaneus overlap in the views
    np.testing.assert_allclose(jb.information, jb.information.T)
    for k in range(2):
        own = pose_bound(r, k, P[k], c[k], line_integral=L, quanta_per_pixel=3000.0)
        np.testing.assert_allclose(jb.known[k].information, own.information, rtol=1e-9)
        # the other bone unknown: the bone's covariance is at least the known-others one (PSD order)
        assert _psd(jb.joint[k].covariance - own.covariance, np.abs(own.covariance).max())
        assert jb.joint[k].rms_mm >= own.rms_mm and jb.joint[k].rms_deg >= own.rms_deg
        # its information is the Schur complement of the other bone's block
        o = slice(6 * (1 - k), 6 * (1 - k) + 6)
        s = slice(6 * k, 6 * k + 6)
        schur = jb.information[s, s] - jb.information[s, o] @ np.linalg.solve(jb.information[o, o],
                                                                            jb.information[o, s])
        np.testing.assert_allclose(jb.joint[k].information, schur, rtol=1e-6, atol=1e-9 * np.abs(schur).max())
    d = jb.to_dict()
    assert d["bones"] == [0, 1] and len(d["joint"]) == len(d["known"]) == 2
    # a bone outside every view is left out: the other's joint bound is then its own
    away = P.copy()
    away[1, :3, 3] += 5000.0
    jm = joint_bound(r, [0, 1], away, c, line_integral=L, quanta_per_pixel=3000.0)
    assert jm.bones == (0,) and jm.missing == (1,)
    assert jm.joint[0].rms_mm == pytest.approx(jm.known[0].rms_mm, rel=1e-12)
    away[0, :3, 3] += 5000.0
    with pytest.raises(OutsideViewError):
        joint_bound(r, [0, 1], away, c, line_integral=L, quanta_per_pixel=3000.0)
    with pytest.raises(ValueError, match="poses"):
        joint_bound(r, [0, 1], P[:1], c, line_integral=L, quanta_per_pixel=3000.0)
    with pytest.raises(ValueError, match="distinct"):
        joint_bound(r, [0, 0], P, c, line_integral=L, quanta_per_pixel=3000.0)


def test_a_bone_without_a_finite_bound_leaves_the_others_theirs(pair):
    """A bone whose information is singular (an empty volume: its image never changes) makes only
    the bounds of the bones its region meets infinite: a talus apart from it keeps its own bound, in
    joint_bound and in the study's frame_bounds (its pair with the empty bone the known-others
    bound); non-finite poses and line integrals are refused by name."""
    from dataclasses import replace

    from core.render import DRRRenderer
    from core.studies.tracking.joint_bound import frame_bounds

    r0, P, c = pair
    talus = r0.volumes[0]
    r = DRRRenderer(r0.cameras, [talus, replace(talus, data=np.zeros_like(talus.data))], device="cpu")
    P = np.stack([P[0], P[0]])
    P[1, :3, 3] += (0.0, -60.0, 0.0)  # the empty bone apart from the talus, seen in both views
    C = np.stack([c[0], c[0]])
    L = [_ramp(cam.image_shape) for cam in r.cameras]
    jb = joint_bound(r, [0, 1], P, C, line_integral=L, quanta_per_pixel=3000.0)
    own = pose_bound(r, 0, P[0], C[0], line_integral=L, quanta_per_pixel=3000.0)
    assert np.all(np.isfinite(jb.joint[0].covariance)) and np.all(np.isinf(jb.joint[1].covariance))
    np.testing.assert_allclose(jb.joint[0].covariance, own.covariance, rtol=1e-9)
    np.testing.assert_array_equal(jb.covariance[:6, 6:], 0.0)
    fb = frame_bounds(r, ("talus", "empty"), C, lambda f: P, lambda f: L, [3000.0, 3000.0], [0])
    assert set(fb) == {"talus"} and fb["talus"]["ratio"] == {"mm": 1.0, "deg": 1.0}
    assert fb["talus"]["pairs"]["empty"]["rms_mm"] == pytest.approx(own.rms_mm, rel=1e-12)
    bad = P.copy()
    bad[1, 0, 3] = np.nan
    with pytest.raises(ValueError, match="finite"):
        joint_bound(r, [0, 1], bad, C, line_integral=L, quanta_per_pixel=3000.0)
    u0, v0 = search_roi(r, P[0], 0, views=[0], center=C[0], reach_mm=0.0, margin_px=6)[0][:2]
    L_nan = [x.copy() for x in L]
    L_nan[0][v0 + 2, u0 + 2] = np.nan
    with pytest.raises(ValueError, match=r"line_integral\[0\]"):
        pose_bound(r, 0, P[0], C[0], line_integral=L_nan, quanta_per_pixel=3000.0)


def _joint_ml_fit(r, truth, centers, counts, N, roi, bg, *, fit=(0, 1), iterations=5, h=0.03):
    """Fisher scoring on the Poisson log-likelihood of both bones' line integrals plus the known
    background, the bones in ``fit`` estimated (the others kept at the truth), every realisation at
    once; independent of :mod:`core.tracking.bound` (own renders, own steps, a common ROI per view)."""
    M = len(counts)
    nb = len(truth)
    x = np.zeros((M, nb, 6))
    E = np.concatenate([np.zeros((1, 6)), h * np.eye(6), -h * np.eye(6)])  # (13, 6), mm and degrees
    for _ in range(iterations):
        X = x[:, None] + E[None, :, None]  # (M, 13, nb, 6): every bone moved by the same step
        Xb = [X[:, :, b].reshape(-1, 6) for b in range(nb)]
        P = np.stack([pose_from_params(np.c_[Xb[b][:, :3], np.radians(Xb[b][:, 3:])], center=centers[b],
                                       base=truth[b]) for b in range(nb)], axis=1)
        img = r.render(P, views=[0, 1], bones=list(range(nb)), roi=roi[None, :, None, :]).numpy()
        img = img.reshape(M, 13, 2, nb, *counts.shape[-2:]).astype(float)  # (M, 13, view, bone, H, W)
        lam = N * np.exp(-(img[:, 0].sum(axis=2) + bg))  # (M, 2, H, W)
        dL = (img[:, 1:7] - img[:, 7:]) / (2 * h)  # (M, 6, view, bone, H, W)
        G = np.concatenate([dL[:, :, :, b] for b in fit], axis=1).reshape(M, 6 * len(fit), -1)
        lam_f, n_f = lam.reshape(M, -1), counts.reshape(M, -1)
        info = np.einsum("mip,mp,mjp->mij", G, lam_f, G)
        score = np.einsum("mip,mp->mi", G, lam_f - n_f)
        step = np.linalg.solve(info, score[..., None])[..., 0].reshape(M, len(fit), 6)
        for k, b in enumerate(fit):
            x[:, b] += step[:, k]
    return x  # (M, nb, 6): the estimate's parameters from the truth


def test_joint_bound_is_the_spread_of_a_joint_maximum_likelihood_fit():
    """Two copies of the talus 1.5 mm apart: their edges run side by side in both views, as the
    congruent articular surfaces of neighbouring bones do, so that moving one bone can be mistaken
    for moving the other (strong overlap). Poisson frames, both bones fitted together from the
    truth: the fit's spread is the joint bound, well above the bound with the other bone known."""
    from core.render import DRRRenderer
    from core.synthetic import make_foot_scene
    from core.tracking.bones import bone_model

    sc = make_foot_scene(n_frames=1, pixels=80, spacing=1.5, names=("talus",), beads_per_bone=0,
                         phase=(0.0, 0.01), soft_tissue=False, imaging="ideal", floor_thickness_mm=0)
    vol = sc.bones[0].to_attenuation(sc.bone_transfer)
    r = DRRRenderer(sc.rig, [vol, vol], device="cpu")
    c = bone_model(sc.bones[0], mesh=False).centroid
    P0 = sc.poses(0)[0]
    truth = np.stack([P0, pose_from_params(np.array([[1.5, 0, 0, 0, 0, 0]]), center=c, base=P0)[0]])
    centers = np.stack([c, c])
    rois = [search_roi(r, truth[b], b, views=(0, 1), center=c, reach_mm=2.0, margin_px=6) for b in range(2)]
    lo = np.minimum(rois[0][:, :2], rois[1][:, :2])
    hi = np.maximum(rois[0][:, :2] + rois[0][:, 2:], rois[1][:, :2] + rois[1][:, 2:])
    roi = np.c_[lo, hi - lo]  # per view the box around both bones
    H, W = int(roi[:, 3].max()), int(roi[:, 2].max())
    img = r.render(truth[None], views=[0, 1], bones=[0, 1], roi=roi[None, :, None, :]).numpy()[0]
    L_true = img.astype(float).sum(axis=1)  # (2, H, W)
    full, bg = [], np.zeros((2, H, W))
    valid = np.zeros((2, H, W), bool)
    for v, cam in enumerate(r.cameras):
        u0, v0, w, h = roi[v]
        f = _ramp(cam.image_shape)
        bg[v, :h, :w] = f[v0:v0 + h, u0:u0 + w]
        valid[v, :h, :w] = True
        f[v0:v0 + h, u0:u0 + w] += L_true[v, :h, :w]
        full.append(f)
    N = 300000.0  # enough quanta that the fit is in its linear (efficient) regime
    jb = joint_bound(r, [0, 1], truth, centers, line_integral=full, quanta_per_pixel=N)
    ratio = jb.ratio()
    assert np.all(ratio > 1.25)  # strong overlap: the other bone unknown costs a quarter or more

    g = np.random.default_rng(1)
    M = 64
    lam = N * np.exp(-(L_true + bg))
    counts = np.where(valid, g.poisson(np.broadcast_to(lam, (M, 2, H, W))), lam)
    x = _joint_ml_fit(r, truth, centers, counts, N, roi, bg)
    e = x.reshape(M, 12)
    # the parameters are the registration's (centroid displacement, rotation vector in degrees):
    # the same as acceptance's pose errors to first order
    p0 = pose_from_params(np.c_[x[:, 0, :3], np.radians(x[:, 0, 3:])], center=c, base=truth[0])
    np.testing.assert_allclose([pose_errors(p, truth[0], c) for p in p0[:4]], x[:4, 0], atol=1e-3)
    for k in range(2):
        emp_mm = np.sqrt(np.mean(np.sum(x[:, k, :3] ** 2, axis=1)))
        emp_deg = np.sqrt(np.mean(np.sum(x[:, k, 3:] ** 2, axis=1)))
        # the joint ML estimate is efficient: its spread is the joint bound (64 draws: ±~10-15 %) …
        assert emp_mm / jb.joint[k].rms_mm == pytest.approx(1.0, abs=0.25)
        assert emp_deg / jb.joint[k].rms_deg == pytest.approx(1.0, abs=0.25)
        # … and above the known-others bound, which it cannot reach
        assert emp_mm > 1.1 * jb.known[k].rms_mm and emp_deg > 1.05 * jb.known[k].rms_deg
    # the overall scale: E[eᵀ J e] = 12 (chi-square, 12 degrees of freedom). It does not tell the
    # two bounds apart: the known-others covariance (J's diagonal blocks inverted) gives 12 too
    m = np.mean(np.einsum("mi,ij,mj->m", e, jb.information, e))
    assert 9.0 < m < 15.5
    # what does: per bone, eₖᵀ Sₖ eₖ (Sₖ the Schur complement, the joint bound's information) has
    # mean 6 at the joint covariance, and eₖᵀ Jₖₖ eₖ (the known-others information) has mean
    # trace(Jₖₖ Cₖₖ), 16.7 here, where it would be 6 at the known-others covariance (64 draws: the
    # first's mean within ±0.43 × 4 of 6)
    for k in range(2):
        s = slice(6 * k, 6 * k + 6)
        m_joint = np.mean(np.einsum("mi,ij,mj->m", x[:, k], jb.joint[k].information, x[:, k]))
        m_known = np.mean(np.einsum("mi,ij,mj->m", x[:, k], jb.known[k].information, x[:, k]))
        expected = np.trace(jb.information[s, s] @ jb.covariance[s, s])
        assert expected > 12.0  # the overlap is strong: the two bounds' predictions are far apart
        assert 4.3 < m_joint < 7.7
        assert m_known == pytest.approx(expected, rel=0.3) and m_known > 10.0
    # with the other bone known (kept at the truth) the same frames give the known-others bound
    x1 = _joint_ml_fit(r, truth, centers, counts, N, roi, bg, fit=(0,))
    for u, s in (("mm", slice(0, 3)), ("deg", slice(3, 6))):
        known = np.sqrt(np.mean(np.sum(x1[:, 0, s] ** 2, axis=1)))
        joint = np.sqrt(np.mean(np.sum(x[:, 0, s] ** 2, axis=1)))
        assert known / getattr(jb.known[0], f"rms_{u}") == pytest.approx(1.0, abs=0.25)
        assert joint > 1.2 * known  # on the same frames, not knowing the other bone costs precision


def test_study_bounds_both_ways_and_restates_a_stored_run():
    from core.studies.tracking import acceptance
    from core.studies.tracking.joint_bound import bounds, restate

    ts = acceptance.TrackingScene(n_frames=2, pixels=96, spacing=1.5, device="cpu", correction="exact")
    b = bounds(ts, [0, 1])
    assert set(b) == set(ts.names)
    known = acceptance.cramer_rao(ts, [0, 1])  # the acceptance study's bound is the known-others one
    for n, t in b.items():
        assert t["frames"] == [0, 1] and set(t["pairs"]) == set(ts.names) - {n}
        assert t["known"]["rms_mm"] == pytest.approx(known[n]["rms_mm"], rel=1e-9)
        assert t["known"]["rms_deg"] == pytest.approx(known[n]["rms_deg"], rel=1e-9)
        assert t["ratio"]["mm"] >= 1 - 1e-12 and t["ratio"]["deg"] >= 1 - 1e-12
        for p in t["pairs"].values():  # one other bone unknown: between the two bounds
            assert t["known"]["rms_mm"] * (1 - 1e-9) <= p["rms_mm"] <= t["joint"]["rms_mm"] * (1 + 1e-9)
    n = ts.names[1]
    jm = b[n]["joint"]["rms_mm"]
    E = np.zeros((3, 6))
    E[0, 0], E[1, 0], E[2, 3] = 0.5 * jm, 5 * jm, 0.01  # frame 11 over 4× the joint bound, not flagged
    stored = {"runs": {"joint": {"tracking": {n: {
        "per_frame_error": E.tolist(), "frames_with_pose": [10, 11, 12], "flagged_frames": [12],
        "cramer_rao": {"rms_mm": 2 * jm, "rms_deg": 1.0}}}}}}
    r = restate(stored, b, same_size=True)["joint"][n]
    rms = np.sqrt(np.mean(np.sum(E[:, :3] ** 2, axis=1)))
    assert r["rms_error"]["mm"] == pytest.approx(rms)
    assert r["over_joint"]["mm"] == pytest.approx(rms / jm)
    assert r["over_stored_known"]["mm"] == pytest.approx(rms / (2 * jm))
    assert r["over_4x_joint"] == {"frames": [11], "silent": [11]}
    s = restate(stored, b, same_size=False)["joint"][n]
    assert "over_joint" not in s and "over_known" not in s
    assert s["over_joint_scaled"]["mm"] == pytest.approx(rms / (2 * jm * b[n]["ratio"]["mm"]))


def test_hard_trial_bounds_use_the_frames_volumes(talus_scene):
    """On a stand-in for the harder trial (one bone, the frames' volume and the tracker's CT apart)
    the bounds come from the frames' volume, as the harder trial's own bound (truth_bounds)."""
    from types import SimpleNamespace

    from core.studies.tracking.hard_trial import truth_bounds
    from core.studies.tracking.joint_bound import hard_bounds

    sc, model = talus_scene["scene"], talus_scene["model"]
    scene = SimpleNamespace(rig=sc.rig, bones=sc.bones, bone_transfer=sc.bone_transfer,
                            imaging=[SimpleNamespace(photons_per_pixel=5000.0)] * len(sc.rig))
    L = {f: np.stack([_ramp(cam.image_shape) for cam in sc.rig]) for f in (0, 1)}
    hr = SimpleNamespace(scene=scene, names=("talus",), models=[model], truth=lambda f: sc.poses(f)[:1],
                         line_integrals=L.__getitem__, renderer=None, device="cpu")
    got = hard_bounds(hr, [0, 1])["talus"]
    ref = truth_bounds(scene, hr.names, [model.centroid], hr.truth, hr.line_integrals, [0, 1], device="cpu")
    rms = np.sqrt(np.mean(ref["talus"] ** 2, axis=0))  # the RMS of the per-frame bounds
    assert got["known"]["rms_mm"] == pytest.approx(rms[0], rel=1e-9)
    assert got["joint"]["rms_deg"] == pytest.approx(rms[1], rel=1e-9)  # one bone: nothing else unknown
    assert got["frames"] == [0, 1] and got["pairs"] == {}


def test_study_refuses_a_stored_run_of_another_seed(monkeypatch, tmp_path):
    """The study's seed (acceptance --seed) and the stored run's must be the same scene: a held-out
    run is not re-expressed against seed 0's bounds (refused before any bound is computed), and
    with --seed N the default stored run (seed 0's) is left out."""
    import json

    from core.studies.tracking import joint_bound

    f = tmp_path / "seed3.json"
    cfg = {"seed": 3, "pixels": 64, "voxel_mm": 2.0, "frames": 3}
    f.write_text(json.dumps({"seed": 3, "runs": {"joint": {"config": cfg, "tracking": {}}}}))
    with pytest.raises(ValueError, match="seed 3"):
        joint_bound.run(quick=True, device="cpu", stored=str(f))
    calls = []
    monkeypatch.setattr(joint_bound, "run", lambda **kw: calls.append(kw) or {})
    monkeypatch.setattr("core.io.atomic.print_json", lambda obj, out=None: None)
    joint_bound.main(["--quick", "--seed", "3"])
    joint_bound.main(["--quick"])
    joint_bound.main(["--quick", "--seed", "3", "--stored", str(f)])
    assert [(c["seed"], c["stored"]) for c in calls] == [(3, None), (0, joint_bound.STORED), (3, str(f))]
