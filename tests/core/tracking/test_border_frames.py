"""core.studies.tracking.border_frames: the trial's frames with the border replicated (as the trial
makes them), black (as a lab's pipeline leaves it) or never distorted."""

from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from core.studies.tracking import border_frames


def _ts(pixels: int = 96):
    from core.synthetic import ImagingModel, foot_rig

    rig = foot_rig(seed=0, pixels=pixels)
    g = np.random.default_rng(3)
    models = [ImagingModel.fluoroscope(c, rng=g) for c in rig]
    scene = SimpleNamespace(rig=rig, imaging=models,
                            frame_rng=lambda i, v: np.random.default_rng([int(i), int(v)]))
    return SimpleNamespace(scene=scene, _scene_renderer=None), models


def test_frame_kinds_differ_only_where_the_correction_leaves_the_detector():
    ts, models = _ts()
    yy, xx = np.mgrid[0:96, 0:96]
    L = np.stack([0.5 + 0.3 * np.sin(xx / 7.0) * np.cos(yy / 9.0)] * 2).astype(np.float32)
    rep = border_frames.frame_images(ts, 1, "replicate", L=L)
    blk = border_frames.frame_images(ts, 1, "black", L=L)
    und = border_frames.frame_images(ts, 1, "undistorted", L=L, noise=False)
    for v, m in enumerate(models):
        d = m.distortion
        uv = np.stack([xx.ravel(), yy.ravel()], axis=1).astype(float)
        f = d.forward(uv)
        out = ((f[:, 0] < -1) | (f[:, 0] > 96) | (f[:, 1] < -1) | (f[:, 1] > 96)).reshape(96, 96)
        inner = ((f[:, 0] > 1) & (f[:, 0] < 94) & (f[:, 1] > 1) & (f[:, 1] < 94)).reshape(96, 96)
        assert out.any() and inner.any()
        assert np.array_equal(rep[v][inner], blk[v][inner])  # the same raw frame and noise draw
        assert np.all(blk[v][out] == 0) and np.all(rep[v][out] > 0.2)
        plain = replace(m, distortion=None, photons_per_pixel=None, read_noise_dn=0.0)
        assert np.array_equal(und[v], plain.to_float(plain.apply(L[v])))
    with pytest.raises(ValueError, match="kind"):
        border_frames.frame_images(ts, 1, "reflect", L=L)


def test_fill_keeps_the_usable_pixels_and_removes_the_rim_step():
    yy, xx = np.mgrid[0:64, 0:64]
    img = np.where(np.hypot(xx - 32, yy - 32) < 28, 0.3 + 0.001 * xx, 0.0).astype(np.float32)
    trial = border_frames.prepared([img], "trial", 2.0)
    fill = border_frames.prepared([img], "fill", 2.0)
    wide = border_frames.prepared([img], "erode", 2.0)
    li_t, m_t = trial.region(0, slice(0, 64), slice(0, 64))
    li_f, m_f = fill.region(0, slice(0, 64), slice(0, 64))
    _, m_w = wide.region(0, slice(0, 64), slice(0, 64))
    assert np.array_equal(m_t, m_f) and m_t.sum() > m_w.sum() > 0 and not np.any(m_w & ~m_t)
    assert np.allclose(li_f[m_t], li_t[m_t])
    assert li_t.max() > 8.0 and li_f.max() < 1.3  # no -log(floor) step outside the field
    with pytest.raises(ValueError, match="prep"):
        border_frames.prepared([img], "inpaint", 2.0)
