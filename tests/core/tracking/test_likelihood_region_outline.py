"""The likelihood stage's region from the bone's DRR support (final_stage.REGION_OUTLINE, opt-in):
the support's hull holds every voxel the DRR can touch, its region lies inside the volume box's, and
the stage with it lands near the stage with the box on an ideal 128² talus frame."""

from __future__ import annotations

import numpy as np

from core.tracking.cost import prepare_frame, search_roi
from core.tracking.roi import support_points


def test_support_points_hold_the_positive_voxels(talus_scene):
    from scipy.spatial import Delaunay

    r = talus_scene["renderer"]
    vol = r.volumes[0]
    P = support_points(r, 0)
    assert P is support_points(r, 0) and not P.flags.writeable  # (kept per renderer)
    k, j, i = np.nonzero(np.asarray(vol.data) > 0)
    inside = Delaunay(P).find_simplex(vol.index_to_physical(np.column_stack([i, j, k]).astype(float)))
    assert (inside >= 0).all()
    sc, model = talus_scene["scene"], talus_scene["model"]
    pose = sc.poses(2)[0]
    box = search_roi(r, pose, 0, views=(0, 1), center=model.centroid, reach_mm=1.0, margin_px=4)
    tight = search_roi(r, pose, 0, views=(0, 1), center=model.centroid, reach_mm=1.0, margin_px=4, points=P)
    assert (tight[:, :2] >= box[:, :2]).all()
    assert (tight[:, :2] + tight[:, 2:] <= box[:, :2] + box[:, 2:]).all()
    assert (tight[:, 2] * tight[:, 3]).sum() < (box[:, 2] * box[:, 3]).sum()


def test_the_stage_on_the_support_region(talus_scene, monkeypatch):
    import core.tracking.final_stage as fst
    from core.tracking.register import RegistrationOptions, RegistrationResult

    sc, model, r = talus_scene["scene"], talus_scene["model"], talus_scene["renderer"]
    truth = sc.poses(2)[0]
    frame = prepare_frame(talus_scene["fluence"](2), valid_range=None)
    res = RegistrationResult(pose=truth, x=np.zeros(6), score=0.0, view_scores=np.zeros(2), evaluations=0,
                             generations=0, time_s=0.0, converged=True, reason="", stages=(), timing={})
    so = RegistrationOptions(bounds=(3.0, 3.0), search="newton", final="likelihood", final_highpass_px=2.0)
    seen = []
    plain = fst.snap_roi
    monkeypatch.setattr(fst, "snap_roi", lambda *a, **k: seen.append(plain(*a, **k)) or seen[-1])
    out = {}
    for ext in (None, 2.0):
        monkeypatch.setattr(fst, "REGION_OUTLINE", ext)
        out[ext] = fst.final_stage(r, frame, res, bone=0, initial_pose=truth, center=model.centroid,
                                   options=so, views=(0, 1))
        assert out[ext].timing["likelihood_taken"] == 1
    box, tight = seen
    assert (tight[:, 2] * tight[:, 3]).sum() < (box[:, 2] * box[:, 3]).sum()
    a, b = out[None].pose, out[2.0].pose
    assert np.linalg.norm(a[:3, 3] - b[:3, 3]) < 0.05
    assert np.degrees(np.arccos(np.clip((np.trace(a[:3, :3] @ b[:3, :3].T) - 1) / 2, -1, 1))) < 0.1


def test_buffers_kept_per_size_give_the_same_steps(talus_scene, monkeypatch):
    """likelihood_launches.BUFFERS_PER_SIZE: regions of two sizes in turn reuse each size's buffers
    (the same addresses when a size comes back) and give the steps of buffers made anew, to the bit."""
    import core.tracking.likelihood_launches as LL
    from core.tracking.engine_likelihood import LikelihoodEngine

    sc, model, r = talus_scene["scene"], talus_scene["model"], talus_scene["renderer"]
    frame = prepare_frame(talus_scene["fluence"](2), valid_range=None)
    pose = sc.poses(2)[0]
    box = search_roi(r, pose, 0, views=(0, 1), center=model.centroid, reach_mm=1.0, margin_px=4)
    small = box + np.array([8, 8, -16, -16])  # (a smaller output size)
    out = {}
    for flag in (False, True):
        monkeypatch.setattr(LL, "BUFFERS_PER_SIZE", flag)
        eng = LikelihoodEngine(r, bone=0, views=(0, 1), highpass_px=2.0)
        steps, ptrs = [], []
        for roi in (box, small, box):
            eng.set_frame(frame, base_pose=pose, center=model.centroid, roi=roi)
            ptrs.append(eng._bufs["li"].ptr)
            steps.append(eng.step(np.full(6, 0.01), np.full(6, 0.05)))
        out[flag] = steps
        if flag:
            assert ptrs[0] == ptrs[2] != ptrs[1]
    for a, b in zip(out[False], out[True], strict=True):
        for k in ("JJ", "Jr", "chi2", "M"):
            np.testing.assert_array_equal(a[k], b[k])


def test_support_points_of_a_volume_in_hu(talus_scene):
    """A volume in HU: the support is where the renderer's transfer gives μ > 0 (HU above -1000 with
    the default transfer, not HU > 0; above the threshold with one)."""
    from scipy.spatial import Delaunay

    from core.render import DRRRenderer
    from core.render.volume import CTVolume, HUTransfer

    hu = np.full((10, 12, 14), -500.0, dtype=np.float32)  # (fat-like: μ > 0, HU < 0)
    hu[3:7, 4:8, 5:9] = 400.0
    vol = CTVolume(hu, spacing=np.full(3, 2.0), origin=np.array([-14.0, -12.0, -10.0]), units="HU")
    for tr in (None, HUTransfer(threshold=150.0)):
        r = DRRRenderer(talus_scene["scene"].rig, [vol], transfer=tr, device="cpu")
        P = support_points(r, 0)
        k, j, i = np.nonzero(r.transfer(hu) > 0)
        assert len(k) == (hu.size if tr is None else 64)
        inside = Delaunay(P).find_simplex(vol.index_to_physical(np.column_stack([i, j, k]).astype(float)))
        assert (inside >= 0).all()
