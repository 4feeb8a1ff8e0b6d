"""The likelihood stage's faster kernels on Warp's CPU device: the blocked blur and the median's
count by bisection give the values of the kernels they replace, to the bit; the design's
differences blurred instead of its images give the same moments up to float32 rounding, the same
sandwich at one design, and through the stage (its uphill test on resolved steps only,
engine_likelihood.UPHILL_RESOLVED) poses and σ within the stage's own spread under a perturbation
of rounding's size (core.tracking.likelihood_fast: Rounding)."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp


@pytest.mark.parametrize("sigma", [2.0, 8.0])
def test_blocked_blur_is_the_plain_blur_to_the_bit(sigma):
    from core.similarity import _kernels as K
    from core.similarity.batched import gaussian_weights
    from core.tracking.likelihood_fast import blur_block_dim, blur_block_kernel

    g = np.random.default_rng(1)
    x = g.normal(size=(6, 37, 45)).astype(np.float32)
    x[0, 3, 5] = np.nan
    src = wp.array(x, dtype=wp.float32, device="cpu")
    ref = wp.array(np.array([[37, 45], [29, 40], [33, 7]], np.int32), dtype=wp.vec2i, device="cpu")
    taps = wp.array(gaussian_weights(sigma, truncate=4.0), dtype=wp.float32, device="cpu")
    for axis in (0, 1):
        a = wp.zeros(x.shape, dtype=wp.float32, device="cpu")
        b = wp.full(x.shape, 7.0, dtype=wp.float32, device="cpu")
        wp.launch(K.blur_kernel, dim=x.shape, inputs=[src, a, taps, ref, 3, axis], device="cpu")
        wp.launch(blur_block_kernel, dim=blur_block_dim(x.shape, axis), inputs=[src, b, taps, ref, 3, axis],
                  device="cpu")
        np.testing.assert_array_equal(a.numpy(), b.numpy())


def test_median_by_bisection_is_the_counted_one(monkeypatch):
    import core.tracking.likelihood_kernels as lk

    g = np.random.default_rng(2)
    e = g.normal(0.0, 1.0, (2, 40, 52)).astype(np.float32)
    w = g.uniform(0.5, 2.0, e.shape).astype(np.float32)
    w[0, :, 40:] = 0.0
    w[1, 10:13, :] = 0.0
    w[1, 0, 1] = 0.0  # (an odd count in one view, an even one in the other)
    e = np.where(w > 0, e, 0.0).astype(np.float32)
    out = []
    for bisect in (False, True):
        monkeypatch.setattr(lk, "MEDIAN_BISECT", bisect)
        f = lk.robust_factors_device(wp.array(e, dtype=wp.float32, device="cpu"),
                                     wp.array(w, dtype=wp.float32, device="cpu"), 2.5)
        out.append(f.numpy())
    np.testing.assert_array_equal(out[0], out[1])


def test_differences_blurred_give_the_same_moments(talus_scene, monkeypatch):
    import core.tracking.engine_likelihood as el
    from core.tracking.cost import prepare_frame, search_roi, snap_roi

    sc, model, r = talus_scene["scene"], talus_scene["model"], talus_scene["renderer"]
    truth = sc.poses(1)[0]
    fr = prepare_frame(talus_scene["fluence"](1), valid_range=None)
    roi = snap_roi(search_roi(r, truth, 0, views=(0, 1), center=model.centroid, reach_mm=1.0, margin_px=4),
                   r, (0, 1))
    x = np.r_[0.2, -0.1, 0.1, 0.3, -0.2, 0.1]
    M, res = [], []
    for diff in (False, True):
        monkeypatch.setattr(el, "DIFF_IMAGES", diff)
        eng = el.LikelihoodEngine(r, bone=0, views=(0, 1), highpass_px=2.0)
        eng.set_frame(fr, base_pose=truth, center=model.centroid, roi=roi)
        s = eng.step(x, np.full(6, 0.05))
        M.append(s["M"])
        res.append(eng.residual(s))
    assert np.abs(M[0]).max() > 0
    np.testing.assert_allclose(M[1], M[0], rtol=1e-4, atol=1e-6 * np.abs(M[0]).max())
    np.testing.assert_allclose(res[1], res[0], atol=1e-4 * np.abs(res[0]).max())


@pytest.fixture(scope="module")
def noisy_talus():
    """The talus alone in 128² fluoroscope views (quantum noise, soft tissue; the distortion undone),
    1.5 mm voxels: a frame whose residual is more than noise, as the trials' are."""
    from core.render import DRRRenderer
    from core.synthetic import make_foot_scene
    from core.tracking.bones import bone_model
    from core.tracking.cost import prepare_frame

    sc = make_foot_scene(n_frames=4, pixels=128, spacing=1.5, names=("talus",), beads_per_bone=0,
                         floor_thickness_mm=0)
    r = DRRRenderer(sc.rig, [sc.bones[0].to_attenuation(sc.bone_transfer)], device="cpu")

    def frame(i):
        out = []
        for m, f in zip(sc.imaging, sc.render_frame(i), strict=True):
            img = m.to_float(f)
            out.append(img if m.distortion is None else m.distortion.unwarp(img))
        return prepare_frame(out, valid_range=None)

    return {"scene": sc, "model": bone_model(sc.bones[0], mesh=False), "renderer": r, "frame": frame}


def test_differences_give_the_same_sandwich(noisy_talus, monkeypatch):
    """At one design the two paths' confidences agree to float32 rounding (measured 6e-6 relative)."""
    import core.tracking.engine_likelihood as el
    from core.tracking.cost import search_roi, snap_roi

    sc, model, r = noisy_talus["scene"], noisy_talus["model"], noisy_talus["renderer"]
    truth = sc.poses(3)[0]
    fr = noisy_talus["frame"](3)
    roi = snap_roi(search_roi(r, truth, 0, views=(0, 1), center=model.centroid, reach_mm=1.0, margin_px=4),
                   r, (0, 1))
    x, h = np.r_[0.05, -0.03, 0.02, 0.1, -0.05, 0.05], np.full(6, 0.05)
    sig = []
    for diff in (False, True):
        monkeypatch.setattr(el, "DIFF_IMAGES", diff)
        eng = el.LikelihoodEngine(r, bone=0, views=(0, 1), highpass_px=4.0)
        eng.set_frame(fr, base_pose=truth, center=model.centroid, roi=roi)
        s = eng.step(x, h)
        hinv = np.linalg.inv(s["JJ"])
        sig.append(np.sqrt(np.r_[np.diag(eng.sandwich(s, hinv)), np.diag(hinv * s["chi2"])]))
    assert np.all(np.isfinite(sig[0])) and np.all(sig[0] > 0)
    np.testing.assert_allclose(sig[1], sig[0], rtol=1e-4)


@pytest.mark.parametrize("frame", [1, 3])
def test_stage_the_same_with_differences(noisy_talus, monkeypatch, frame):
    """Through the final stage (robust round, σ of the sandwich plus the move): the differenced path,
    and the plain one with its first refinement started 1e-6 off, give poses within 3e-3 σ and σ
    within 3e-3 relative of the plain path's (measured at most 1.4e-3 and 1.1e-3 on frames 1-5, high
    pass 2 and 4 px; with every rise of χ² taken as uphill, UPHILL_RESOLVED 0, the 1e-6 start moved
    the pose by up to 1.8e-2 σ, the differences by up to 4e-3 σ)."""
    import core.tracking.engine_likelihood as el
    from core.studies.tracking.stage_speed import _jitter
    from core.tracking.register import RegistrationOptions, register

    sc, model, r = noisy_talus["scene"], noisy_talus["model"], noisy_talus["renderer"]
    truth = sc.poses(frame)[0]
    fr = noisy_talus["frame"](frame)
    o = RegistrationOptions(bounds=(3.0, 3.0), search="newton", final="likelihood", final_highpass_px=2.0)
    out = []
    for diff, eps in ((False, 0.0), (True, 0.0), (False, 1e-6)):
        monkeypatch.setattr(el, "DIFF_IMAGES", diff)
        with _jitter(eps):
            res = register(r, fr, bone=0, initial_pose=truth, center=model.centroid, options=o)
        assert res.timing["likelihood_taken"] == 1
        out.append((np.asarray(res.x, float), np.sqrt(np.diag(res.fit.covariance))))
    x0, s0 = out[0]
    assert np.all(np.isfinite(s0)) and np.all(s0 > 0)
    for x, s in out[1:]:
        assert np.max(np.abs(x - x0) / s0) < 3e-3
        assert np.max(np.abs(s - s0) / s0) < 3e-3
