"""The band at the round field's rim kept between frames (core.tracking.likelihood_rim.RimCache):
the same band, to the bit, as computed afresh, whether a frame's black pixels are those of the
last frame (a hit), differ at a few noisy rim pixels or along a collimator edge (updated around
them), and the engine's second frame with the same field reuses it."""

from __future__ import annotations

import numpy as np

from core.tracking.cost import prepare_frame, search_roi, snap_roi
from core.tracking.likelihood_rim import RimCache, _boxes, apply_rim, rim_cache, rim_keep


def _noisy_field(seed: int, n: int = 128, collimator: int | None = None) -> list[np.ndarray]:
    """Two views of a round field (radius 56 px) whose rim pixels are partly covered and noisy, so
    that some cross the black threshold from frame to frame; ``collimator``: black above that row."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[:n, :n]
    cover = np.clip(56.5 - np.hypot(xx - 64, yy - 60), 0.0, 1.0)
    f = cover * (0.3 + 0.2 * np.sin(xx / 9.0))
    f = rng.poisson(f * 400.0) / 400.0 + rng.normal(0.0, 0.001, f.shape)
    if collimator is not None:
        f[:collimator] = 0.0
    f = np.clip(f, 0.0, 1.0).astype(np.float32)
    return [f, f[::-1].copy()]


def test_cached_band_is_the_band_afresh():
    frames = [prepare_frame(_noisy_field(s, collimator=14 if s == 4 else None)) for s in range(7)]
    rng = np.random.default_rng(3)
    cache = RimCache()
    for k in range(21):
        fr = frames[k % len(frames)]
        roi = np.array([[16 * int(rng.integers(0, 3)), 16 * int(rng.integers(0, 3)), 64, 80],
                        [16 * int(rng.integers(0, 4)), 16 * int(rng.integers(0, 2)), 48, 64]])
        radius = (6.0, 12.0, 7.5)[k % 3]
        a = rim_keep(fr, (0, 1), roi, radius, (96, 80))
        b = rim_keep(fr, (0, 1), roi, radius, (96, 80), cache=cache)
        assert (a is None) == (b is None) and (a is None or np.array_equal(a, b)), k
    s = cache.stats()
    assert s["built"] == 6 and s["patched"] > 0 and s["hits"] > 0, s  # (2 views x 3 radii)
    # the same frame again (other regions): every region a hit
    rim_keep(frames[0], (0, 1), np.array([[0, 0, 64, 80], [0, 0, 48, 64]]), 6.0, (96, 80), cache=cache)
    hits = cache.hits
    rim_keep(frames[0], (0, 1), np.array([[16, 0, 64, 80], [0, 16, 48, 64]]), 6.0, (96, 80), cache=cache)
    assert cache.hits == hits + 2
    small = RimCache(size=2)
    for radius in (4.0, 5.0, 6.0):
        rim_keep(frames[0], (0,), np.array([[0, 0, 64, 80]]), radius, (96, 80), cache=small)
    assert len(small._fields) == 2 and small.built == 3


def test_boxes_group_near_pixels():
    ys, xs = np.array([10, 12, 60, 61, 11]), np.array([10, 11, 90, 90, 40])
    assert sorted(_boxes(ys, xs, 3)) == [(10, 13, 10, 12), (11, 12, 40, 41), (60, 62, 90, 91)]
    assert sorted(_boxes(ys, xs, 15)) == [(10, 13, 10, 41), (60, 62, 90, 91)]
    many = np.arange(100)
    assert _boxes(many, many, 1) == [(0, 100, 0, 100)]


def test_second_frame_with_the_same_field_hits_the_engines_cache(talus_scene):
    from core.tracking.engine_likelihood import LikelihoodEngine

    sc, bone, r = talus_scene["scene"], talus_scene["model"], talus_scene["renderer"]
    t2 = sc.poses(2)[0]
    c = bone.centroid @ t2[:3, :3].T + t2[:3, 3]
    centres = [cam.project(c[None])[0] for cam in sc.rig]

    def framed(i):  # the same round field (radius 60 px, its rim 10 px from frame 2's bone centre)
        imgs, masks = [], []
        for (px, py), f in zip(centres, talus_scene["fluence"](i), strict=True):
            yy, xx = np.mgrid[:f.shape[0], :f.shape[1]]
            inside = (xx - (px + 50.0)) ** 2 + (yy - py) ** 2 < 60.0 ** 2
            imgs.append(np.where(inside, f, 1 / 4096.0))
            masks.append(inside)
        return prepare_frame(imgs, masks=masks, valid_range=None), sc.poses(i)[0]

    eng = LikelihoodEngine(r, bone=0, views=(0, 1), highpass_px=2.0)
    for i in (2, 3):
        fr, truth = framed(i)
        roi = snap_roi(search_roi(r, truth, 0, views=[0, 1], center=bone.centroid, reach_mm=1.0, margin_px=4),
                       r, (0, 1))
        eng.set_frame(fr, base_pose=truth, center=bone.centroid, roi=roi)
        w0 = eng._w.numpy().copy()
        assert apply_rim(eng, fr, 6.0)
        keep = rim_keep(fr, eng.views, eng.roi, 6.0, eng._cap)  # afresh, no cache
        np.testing.assert_array_equal(eng._w.numpy(), np.where(keep == 0, 0.0, w0).astype(np.float32))
        assert 0 < np.count_nonzero((keep == 0) & (w0 > 0)) < np.count_nonzero(w0)
    assert rim_cache(eng).stats() == {"hits": 2, "patched": 0, "built": 2}
