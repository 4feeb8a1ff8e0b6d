"""The noise correction of the gradient correlation of magnitudes (``noise_correction``): the noise
energy estimated from a frame, and the Gauss–Newton engine's debiased magnitudes against the
numpy reference and the host cost."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy import ndimage

from core.geometry.transforms import pose_from_params
from core.similarity.batched import gaussian_weights
from core.similarity.gradient import (
    frame_noise_energy,
    gradient_correlation,
    noise_energy_of_samples,
    noise_gradient_energy,
)
from core.tracking.cost import (
    DEFAULT_TERMS,
    NOISE_OPTION,
    MetricTerm,
    RegistrationCost,
    fluoro_rois,
    noise_maps,
    prepare_frame,
    search_roi,
)
from core.tracking.engine import GaussNewtonCost, step_design, supports
from core.tracking.register import RegistrationOptions

H = np.array([0.25] * 3 + [0.5] * 3)
# smoothing in pixels (0.3 mm is below a quarter pixel of these 128² views, and would be dropped)
TERM = MetricTerm("gc", 1.0, {"fluoro_sigma": 1.0, "drr_sigma": 1.0, NOISE_OPTION: True})
PLAIN = MetricTerm("gc", 1.0, {"fluoro_sigma": 1.0, "drr_sigma": 1.0})


def _poisson_frame(F, quanta: float, psf: float, seed: int) -> np.ndarray:
    """Quantum noise (``quanta`` per pixel at full fluence), then the detector's blur."""
    g = np.random.default_rng(seed)
    return ndimage.gaussian_filter(g.poisson(quanta * F) / quanta, psf, mode="nearest")


def _anatomy(n: int = 256) -> np.ndarray:
    """Fluence of soft tissue with a textured, dense bone in its middle."""
    y, x = np.mgrid[0:n, 0:n].astype(float)
    r2 = (x - n / 2) ** 2 / (0.3 * n) ** 2 + (y - n / 2) ** 2 / (0.22 * n) ** 2
    inside = np.sqrt(np.clip(1 - r2, 0, None))
    tex = ndimage.gaussian_filter(np.random.default_rng(7).normal(size=(n, n)), 1.5)
    L = 0.3 + 0.2 * x / n + 1.5 * inside + 0.6 * inside * tex / tex.std()
    return np.exp(-L)


@pytest.mark.parametrize("quanta", [300.0, 1200.0])
def test_frame_estimate_recovers_the_noise_of_poisson_frames(quanta):
    """E₁ from one textured frame within 10 % of two flat frames' photon transfer (the
    calibration's measure), at two doses (E₁ ∝ 1 / quanta)."""
    psf, sig = 1.0, 1.0
    F0 = _anatomy()
    flats = [_poisson_frame(np.full((256, 256), 0.5), quanta, psf, 10 + k) for k in range(2)]
    truth = noise_gradient_energy(*flats, fluoro_sigma=sig)
    est = [frame_noise_energy(_poisson_frame(F0, quanta, psf, k), fluoro_sigma=sig) for k in range(2)]
    assert np.allclose(est, truth, rtol=0.1), (est, truth)
    # inside the bone alone the texture's gradients dominate: the reason for the brightest pixels
    inner = frame_noise_energy(_poisson_frame(F0, quanta, psf, 0)[96:160, 80:176], fluoro_sigma=sig,
                               bright_fraction=1.0)
    assert inner > 1.5 * truth


def test_frame_estimate_checks_its_arguments():
    with pytest.raises(ValueError, match="fluence"):
        frame_noise_energy(np.ones(8))
    with pytest.raises(ValueError, match="bright_fraction"):
        frame_noise_energy(np.ones((8, 8)), bright_fraction=0)
    assert frame_noise_energy(np.ones((8, 8))) == 0.0  # no usable pixel (saturated)
    with pytest.raises(ValueError, match="too small"):
        noise_energy_of_samples(np.zeros((200, 9)), fluoro_sigma=1.0)


def test_patch_estimate_is_the_filtered_frames():
    """The smoothed value and gradient from a patch's weights equal the filtered frame's there."""
    from core.imaging.edges import derivative_kernels
    from core.similarity.batched import _smooth_and_gradient
    from core.similarity.gradient import _patch_kernels, _patch_radius

    img = np.random.default_rng(0).random((40, 40))
    for sig in (0.0, 0.6, 1.1):
        R = _patch_radius(sig)
        ys, gu, gv = _smooth_and_gradient(img, sig, *derivative_kernels("sobel"))
        z = img[20 - R:21 + R, 17 - R:18 + R].ravel() @ _patch_kernels(sig, "sobel", R)
        np.testing.assert_allclose(z, [ys[20, 17], gu[20, 17], gv[20, 17]], rtol=1e-10, atol=1e-12)


def test_options_set_the_terms_option():
    o = RegistrationOptions(noise_correction=True)
    assert o.terms[0].options[NOISE_OPTION] is True and o.to_dict()["noise_correction"] is True
    assert NOISE_OPTION not in replace(o, noise_correction=False).terms[0].options
    assert RegistrationOptions().terms == DEFAULT_TERMS
    comp = (replace(DEFAULT_TERMS[0], options={**DEFAULT_TERMS[0].options, "components": True}),)
    assert RegistrationOptions(terms=comp, noise_correction=True).terms == comp  # no pedestal to remove
    assert supports(o.terms)
    with pytest.raises(ValueError, match="noise_correction"):
        RegistrationOptions(noise_correction=1)


def _noisy_setup(sc, frame_no, offset, quanta=150.0):
    m, r = sc["model"], sc["renderer"]
    F = [0.8 * np.asarray(f, np.float64) for f in sc["fluence"](frame_no)]  # an unsaturated background
    frame = prepare_frame([_poisson_frame(f, quanta, 0.7, 3 + v) for v, f in enumerate(F)])
    truth = sc["scene"].poses(frame_no)[0]
    off = np.asarray(offset, dtype=float)
    start = pose_from_params(np.r_[off[:3], np.radians(off[3:])], center=m.centroid, base=truth)
    roi = search_roi(r, start, 0, views=(0, 1), center=m.centroid, reach_mm=7.6, points=m.outline)
    return frame, start, roi


def test_engine_debiased_gc_equals_the_reference(talus_scene):
    """The engine's scores with the correction: those of the host cost (BatchedMetric's
    noise_energy) and, per view, of core.similarity.gradient_correlation(noise_energy=E₁/F_s)."""
    sc = talus_scene
    m, r = sc["model"], sc["renderer"]
    frame, start, roi = _noisy_setup(sc, 2, [0.8, -0.5, 0.4, 1.0, -0.8, 1.2])
    gn = GaussNewtonCost(r, bone=0, views=(0, 1), scale=1.0, term=TERM)
    gn.set_frame(frame, base_pose=start, center=m.centroid, roi=roi)
    X = step_design(np.zeros(6), H)
    rc = RegistrationCost(r, frame, bone=0, base_pose=start, center=m.centroid, roi=roi, terms=(TERM,))
    np.testing.assert_allclose(gn(X), rc(X), atol=2e-5)
    plain = RegistrationCost(r, frame, bone=0, base_pose=start, center=m.centroid, roi=roi, terms=(PLAIN,))
    assert np.max(np.abs(plain(X) - rc(X))) > 1e-3  # the correction changes the cost
    # the numpy reference, view by view, at two poses
    fs, ds = PLAIN.options["fluoro_sigma"], PLAIN.options["drr_sigma"]
    rois, masks = fluoro_rois(r, frame, views=(0, 1), roi=roi)
    E = noise_maps(frame, (0, 1), rois, fs)
    assert all(e.min() > 0 for e in E)
    taps = gaussian_weights(ds).astype(np.float64)
    for x in (np.zeros(6), X[3]):
        _, views = gn.score_and_views(x)
        batch = r.render(gn.poses(x[None])[:, None], views=(0, 1), bones=[0], roi=roi[None, :, None, :])
        imgs = batch.numpy()[0, :, 0]
        for v in range(2):
            h, w = rois[v].shape
            d = np.nan_to_num(imgs[v][:h, :w].astype(np.float64))
            d = ndimage.correlate1d(ndimage.correlate1d(d, taps, 0, mode="nearest"), taps, 1, mode="nearest")
            ref = gradient_correlation(d, rois[v].astype(np.float64), fluoro_sigma=fs, fluoro_mask=masks[v],
                                       noise_energy=E[v])
            assert views[v] == pytest.approx(ref, abs=1e-4)
    # its gradient follows the cost's central differences of the 13 scores (a noisy frame's cost
    # is rough at this scale: the direction, not each component to 5 %)
    s = gn.step(np.zeros(6), H)
    cd = (s.costs[1::2] - s.costs[2::2]) / (2 * H)
    assert s.g @ cd / (np.linalg.norm(s.g) * np.linalg.norm(cd)) > 0.99


def test_engine_with_neighbours_subtracted_equals_the_host_cost(talus_calcaneus_128):
    """Joint tracking's path: the neighbour's DRR subtracted from the regions, the noise's fluence
    taken from the regions before the subtraction (device and host alike)."""
    sc, models, r, frames = talus_calcaneus_128
    frame = prepare_frame([_poisson_frame(0.8 * np.asarray(f, np.float64), 150.0, 0.7, 5 + v)
                           for v, f in enumerate(frames[1])])
    truth = sc.poses(1)
    m = models[0]
    start = pose_from_params(np.r_[0.6, -0.4, 0.3, np.radians([0.8, -0.6, 1.0])], center=m.centroid,
                             base=truth[0])
    roi = search_roi(r, start, 0, views=(0, 1), center=m.centroid, reach_mm=6.0, points=m.outline)
    others = (truth[1:2], [1])
    gn = GaussNewtonCost(r, bone=0, views=(0, 1), scale=1.0, term=TERM)
    gn.set_frame(frame, base_pose=start, center=m.centroid, roi=roi, others=others)
    rc = RegistrationCost(r, frame, bone=0, base_pose=start, center=m.centroid, roi=roi, terms=(TERM,),
                          others=others)
    X = step_design(np.zeros(6), H)
    np.testing.assert_allclose(gn(X), rc(X), atol=2e-5)
    # the next round of joint tracking: the neighbour moved, the same regions (not smoothed again
    # for the noise) give the host cost's values at the new subtraction
    others2 = (pose_from_params(np.r_[0.5, 0.0, -0.4, np.radians([1.0, 0.0, 0.5])], center=models[1].centroid,
                                base=truth[1])[None], [1])
    gn.set_frame(frame, base_pose=start, center=m.centroid, roi=roi, others=others2)
    rc2 = RegistrationCost(r, frame, bone=0, base_pose=start, center=m.centroid, roi=roi, terms=(TERM,),
                           others=others2)
    np.testing.assert_allclose(gn(X), rc2(X), atol=2e-5)
    assert np.max(np.abs(rc2(X) - rc(X))) > 1e-5  # the neighbour's move changed the cost


def test_noise_samples_are_the_frames_patches():
    """The patches drawn are the frame's line integrals about the lattice points kept (a patch
    wholly inside the valid range), as a sliding window cuts them."""
    from core.similarity.gradient import noise_samples

    g = np.random.default_rng(3)
    F = np.clip(_anatomy(96) * np.exp(0.05 * g.normal(size=(96, 96))), 0.0, 1.0).astype(np.float32)
    F[10:14, 30:60] = 1.0  # saturated: patches over them are dropped
    for R, step, mask in ((2, 3, None), (4, 5, F > 0.2)):
        P = noise_samples(F, radius=R, step=step, mask=mask, max_samples=50, bright_fraction=0.5)
        k = 2 * R + 1
        win = np.lib.stride_tricks.sliding_window_view(F, (k, k)).reshape(-1, k * k)
        ref = -np.log(np.clip(win, 1.0 / 4096, 1.0))
        assert len(P) > 20 and P.shape[1] == k * k
        hit = (ref[None, :, :] == P[:, None, :]).all(axis=2)  # each patch is one window
        assert hit.any(axis=1).all()


def test_feed_draws_the_last_frames_noise_samples_ahead():
    """The frame look-ahead draws the noise samples the frames before it drew (in its worker
    thread): the next frame's estimate finds them, with the values drawn at the estimate."""
    from core.tracking.feed import FrameFeed

    g = np.random.default_rng(5)
    frames = {i: [_poisson_frame(0.8 * _anatomy(128), 300.0, 0.7, 10 * i + v) for v in range(2)]
              for i in range(4)}
    feed = FrameFeed(lambda i: frames[i], (0.02, 0.999), 3)
    try:
        e = []
        for i in range(4):
            _, fr = feed.get(i)
            if i + 1 < 4:
                feed.prefetch(i + 1)
            if i >= 2:  # drawn ahead: the previous frames asked for these
                assert set(fr.noise_sample_keys) == {(0, 5), (1, 5)}
            e.append([fr.noise_energy(v, 1.0 + 0.1 * g.random()) for v in range(2)])  # patch radius 5
            fresh = prepare_frame(frames[i])
            for v in range(2):
                np.testing.assert_array_equal(fr._noise[(v, 5)], fresh._noise_samples(v, 5))
    finally:
        feed.close()
