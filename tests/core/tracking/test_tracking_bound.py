"""The Cramér–Rao bound against the spread of a maximum-likelihood estimator on Poisson frames."""

import numpy as np
import pytest

from core.geometry.transforms import pose_from_params
from core.studies.tracking.acceptance import pose_errors
from core.tracking.bound import pose_bound
from core.tracking.cost import OutsideViewError, search_roi


def _background(shape):
    """Tissue line integral in front of the bone: a ramp from 1 to 3 across the image, so that
    the photon weights exp(-L) differ strongly between pixels (and between ROI offsets)."""
    h, w = shape
    return np.broadcast_to(1.0 + 2.0 * np.arange(w) / (w - 1), (h, w)).copy()


def _render(r, P, roi):
    """(B, 2, H, W) bone line integrals at poses P (B, 4, 4) over the fixed ROIs."""
    return r.render(P[:, None], views=[0, 1], bones=[0], roi=roi[None, :, None, :]).numpy()[:, :, 0]


def _ml_fit(r, truth, center, counts, N, roi, bg, iterations=5, h=(0.03, 0.03)):
    """Fisher scoring on the Poisson log-likelihood, every realisation at once (independent of
    :mod:`core.tracking.bound`: own steps, own bookkeeping)."""
    M = len(counts)
    x = np.zeros((M, 6))
    step = np.array([h[0]] * 3 + [h[1]] * 3)
    E = np.concatenate([np.zeros((1, 6)), np.diag(step), -np.diag(step)])  # (13, 6)
    for _ in range(iterations):
        X = (x[:, None, :] + E[None]).reshape(-1, 6)
        P = pose_from_params(np.c_[X[:, :3], np.radians(X[:, 3:])], center=center, base=truth)
        img = _render(r, P, roi).reshape(M, 13, 2, *counts.shape[-2:]).astype(float)
        Lb = img[:, 0]  # (M, 2, H, W)
        dL = (img[:, 1:7] - img[:, 7:]) / (2 * step[None, :, None, None, None])  # (M, 6, 2, H, W)
        lam = N * np.exp(-(Lb + bg))
        G = dL.reshape(M, 6, -1)
        lam_f, n_f = lam.reshape(M, -1), counts.reshape(M, -1)
        info = np.einsum("mip,mp,mjp->mij", G, lam_f, G)
        score = np.einsum("mip,mp->mi", G, lam_f - n_f)  # d log-likelihood / d theta
        x = x + np.linalg.solve(info, score[..., None])[..., 0]
    return pose_from_params(np.c_[x[:, :3], np.radians(x[:, 3:])], center=center, base=truth)


def test_bound_matches_the_spread_of_the_ml_estimate(talus_scene):
    r, model = talus_scene["renderer"], talus_scene["model"]
    truth = talus_scene["scene"].poses(2)[0]
    c = model.centroid
    roi = search_roi(r, truth, 0, views=(0, 1), center=c, reach_mm=2.0, margin_px=6)
    H, W = int(roi[:, 3].max()), int(roi[:, 2].max())
    L_true = _render(r, truth[None], roi)[0].astype(float)  # (2, H, W)
    full, bg = [], np.zeros((2, H, W))
    for v, cam in enumerate(r.cameras):
        img = _background(cam.image_shape)
        u0, v0, w, h = roi[v]
        bg[v, :h, :w] = img[v0:v0 + h, u0:u0 + w]
        img[v0:v0 + h, u0:u0 + w] += L_true[v, :h, :w]
        full.append(img)
    N = 30000.0
    b = pose_bound(r, 0, truth, c, line_integral=full, quanta_per_pixel=N)
    assert b.information.shape == (6, 6) and np.allclose(b.information, b.information.T)
    assert b.pixels > 500 and 0 < b.rms_mm < 0.5 and 0 < b.rms_deg < 1.0

    g = np.random.default_rng(5)
    M = 48
    lam = N * np.exp(-(L_true + bg))
    valid = np.zeros((2, H, W), bool)
    for v in range(2):
        valid[v, : roi[v, 3], : roi[v, 2]] = True
    counts = np.where(valid, g.poisson(np.broadcast_to(lam, (M, 2, H, W))), lam)
    est = _ml_fit(r, truth, c, counts, N, roi, bg)
    err = np.array([pose_errors(p, truth, c) for p in est])
    emp_mm = np.sqrt(np.mean(np.sum(err[:, :3] ** 2, axis=1)))
    emp_deg = np.sqrt(np.mean(np.sum(err[:, 3:] ** 2, axis=1)))
    # the ML estimate is efficient at this photon count: its spread is the bound
    assert emp_mm / b.rms_mm == pytest.approx(1.0, abs=0.25)
    assert emp_deg / b.rms_deg == pytest.approx(1.0, abs=0.25)
    # and the whole covariance agrees: E[eᵀ J e] = 6 for a chi-square with 6 degrees of freedom
    m = np.mean(np.einsum("mi,ij,mj->m", err, b.information, err))
    assert 4.3 < m < 8.0
    # the photon weights matter: without the attenuation in front of the bone the bound is far lower
    flat = pose_bound(r, 0, truth, c, line_integral=[np.zeros(cam.image_shape) for cam in r.cameras],
                      quanta_per_pixel=N)
    assert flat.rms_mm < 0.6 * b.rms_mm
    # four times the quanta halve the bound
    b4 = pose_bound(r, 0, truth, c, line_integral=full, quanta_per_pixel=4 * N)
    assert b4.rms_deg == pytest.approx(b.rms_deg / 2, rel=1e-6)


def test_bound_bad_input(talus_scene):
    r, model = talus_scene["renderer"], talus_scene["model"]
    truth = talus_scene["scene"].poses(0)[0]
    L = [np.zeros(cam.image_shape) for cam in r.cameras]
    with pytest.raises(ValueError, match="line_integral"):
        pose_bound(r, 0, truth, model.centroid, line_integral=L[:1], quanta_per_pixel=100.0)
    with pytest.raises(ValueError, match="quanta_per_pixel"):
        pose_bound(r, 0, truth, model.centroid, line_integral=L, quanta_per_pixel=-1.0)
    away = truth.copy()
    away[:3, 3] += 5000.0
    with pytest.raises(OutsideViewError):
        pose_bound(r, 0, away, model.centroid, line_integral=L, quanta_per_pixel=100.0)
    one = pose_bound(r, 0, truth, model.centroid, line_integral=L, quanta_per_pixel=100.0, views=[0])
    both = pose_bound(r, 0, truth, model.centroid, line_integral=L, quanta_per_pixel=100.0)
    assert both.rms_mm < one.rms_mm  # a second view adds information (depth, above all)


def test_acceptance_bounds_per_bone_and_frames_without_a_bound_are_skipped(monkeypatch):
    from core.studies.tracking import acceptance

    ts = acceptance.TrackingScene(n_frames=2, pixels=96, spacing=1.5, device="cpu")
    out = acceptance.cramer_rao(ts, [0, 1])
    assert set(out) == set(ts.names)
    for b in out.values():
        assert b["frames"] == [0, 1] and np.isfinite(b["rms_mm"]) and np.isfinite(b["rms_deg"])
        assert 0 < b["rms_mm"] < 5 and 0 < b["rms_deg"] < 5 and len(b["sigma"]) == 6
    truth = ts.truth

    def moved(f):  # the talus leaves both views in frame 1
        P = truth(f).copy()
        if f == 1:
            P[1, :3, 3] += 5000.0
        return P

    monkeypatch.setattr(ts, "truth", moved)
    out = acceptance.cramer_rao(ts, [0, 1])
    assert out["talus"]["frames"] == [0] and out["tibia"]["frames"] == [0, 1]


def test_chain_information_reduces_to_the_quantum_bound_and_loses_to_noise_after_the_blur(talus_scene):
    from core.imaging.psf import gaussian_psf
    from core.tracking.bound import chain_information

    r, model = talus_scene["renderer"], talus_scene["model"]
    truth = talus_scene["scene"].poses(2)[0]
    L = [_background(cam.image_shape) for cam in r.cameras]
    kw = {"line_integral": L, "quanta_per_pixel": 5000.0}
    J0 = pose_bound(r, 0, truth, model.centroid, margin_px=8, **kw).information
    kw["margin_px"] = 8
    Jid = chain_information(r, 0, truth, model.centroid, psf=np.ones((1, 1)), added_noise=0.0, **kw)
    np.testing.assert_allclose(Jid, J0, rtol=1e-6)  # identity kernel, no added noise: the same information
    Jb3 = chain_information(r, 0, truth, model.centroid, psf=gaussian_psf(1.2), added_noise=3.0, **kw)
    Jb6 = chain_information(r, 0, truth, model.centroid, psf=gaussian_psf(1.2), added_noise=6.0, **kw)
    # noise after the blur hides what the blur attenuated: less information, the more noise the less
    tol = 1e-6 * np.abs(J0).max()
    assert np.all(np.linalg.eigvalsh(J0 - Jb3) > -tol) and np.all(np.linalg.eigvalsh(Jb3 - Jb6) > -tol)
    assert np.trace(np.linalg.inv(Jb3)) > 1.05 * np.trace(np.linalg.inv(J0))
    with pytest.raises(ValueError, match="psf"):
        chain_information(r, 0, truth, model.centroid, psf=np.ones((2, 2)), added_noise=0.0, **kw)
