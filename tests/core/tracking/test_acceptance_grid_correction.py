"""The acceptance trial's distortion correction estimated from calibration grid frames
(core.studies.tracking.grid_correction; TrackingScene(correction="grid")): the acceptance study's
default, while TrackingScene (the other studies' trial) keeps the true model 3 % off."""

from types import SimpleNamespace

import numpy as np
import pytest

from core.studies.tracking import acceptance, grid_correction


def _views(pixels: int, *, noisy: bool):
    """A two-view rig with its image chains (distortion, and noise when ``noisy``), no bones."""
    from core.synthetic import ImagingModel, foot_rig

    rig = foot_rig(seed=0, pixels=pixels)
    g = np.random.default_rng(3)
    models = [ImagingModel.fluoroscope(c, rng=g) for c in rig]
    if not noisy:
        from dataclasses import replace

        models = [replace(m, photons_per_pixel=None, read_noise_dn=0.0) for m in models]
    return SimpleNamespace(rig=rig, imaging=models, floor=None)


@pytest.mark.parametrize("noisy", [False, True])
def test_grid_correction_leaves_a_small_residual(noisy):
    scene = _views(192, noisy=noisy)
    corr = grid_correction.grid_corrections(scene, n_grid=1)
    rows = grid_correction.residuals(scene, corr)
    for cam, m, c, row in zip(scene.rig, scene.imaging, corr, rows, strict=True):
        uv = grid_correction.field_points(cam, m.distortion)
        raw = np.sqrt(np.mean(np.sum((m.distortion.forward(uv) - uv) ** 2, axis=1)))  # uncorrected
        assert raw > 1.0
        assert row["raw"]["rms_px"] < min(0.1, 0.05 * raw)  # measured: 0.011-0.023 px
        assert c.summary()["model"]  # a model was chosen by cross-validation
        mx, my = c.tables(cam.image_shape)  # the unwarp's tables are the forward map
        p = np.array([[40.0, 60.0], [96.0, 96.0], [150.0, 90.0]])
        q = c.forward(p)
        got = np.array([[mx[int(v), int(u)], my[int(v), int(u)]] for u, v in p])
        assert np.max(np.abs(got - q)) < 1e-3
        assert np.max(np.abs(c.inverse(q) - p)) < 1e-6
        img = np.random.default_rng(0).random(cam.image_shape).astype(np.float32)
        assert c.unwarp(img).shape == img.shape


def test_default_correction_is_the_true_model_three_percent_off():
    ts = acceptance.TrackingScene(n_frames=2, pixels=64, spacing=2.0, device="cpu", names=("talus",),
                                  keep_raw=True)
    assert ts.correction == "model"
    frame = ts.scene.render_frame(1, renderer=ts._scene_renderer)
    for v, (m, c) in enumerate(zip(ts.scene.imaging, ts.corrections, strict=True)):
        d = m.distortion
        assert (c.k1, c.twist_rad) == (d.k1 * 1.03, d.twist_rad * 1.03)
        assert (c.center, c.scale_px, c.k2, c.twist_power) == (d.center, d.scale_px, d.k2, d.twist_power)
        assert np.array_equal(ts.frames(1)[v], c.unwarp(m.to_float(frame[v])))
    assert np.array_equal(ts.raw[1], frame) and ts.residual_distortion_mm() > 0.0
    # the exact correction (study-only oracle): the true model, the kept raw frames corrected again
    ts.use_correction("exact")
    assert ts.correction == "exact" and list(ts._cache) == [1] and ts.residual_distortion_mm() < 1e-9
    for v, (m, c) in enumerate(zip(ts.scene.imaging, ts.corrections, strict=True)):
        assert c.to_dict() == m.distortion.to_dict()
        assert np.array_equal(ts.frames(1)[v], c.unwarp(m.to_float(frame[v])))
    with pytest.raises(ValueError, match="correction"):
        ts.use_correction("truth")
    with pytest.raises(ValueError, match="correction"):
        acceptance.TrackingScene(n_frames=2, pixels=64, spacing=2.0, device="cpu", names=("talus",),
                                 correction="truth")


def test_the_acceptance_study_defaults_to_the_grid_correction(monkeypatch):
    import inspect

    import core.io.atomic

    assert acceptance.DEFAULT_CORRECTION == "grid"
    for f in (acceptance.run, acceptance.tracking_scene):
        assert inspect.signature(f).parameters["correction"].default == "grid"
    seen = {}
    monkeypatch.setattr(acceptance, "run", lambda **kw: seen.update(kw) or {})
    monkeypatch.setattr(core.io.atomic, "print_json", lambda *a, **k: None)
    acceptance.main(["--quick"])
    assert seen["correction"] == "grid"
    acceptance.main(["--quick", "--correction", "model"])
    assert seen["correction"] == "model"
