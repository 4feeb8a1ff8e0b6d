"""The correction pipeline on synthetic trial frames: result, laziness, parallelism, JSON."""

import json
import threading

import numpy as np
import pytest

from core.imaging.distortion import calibrate_distortion
from core.imaging.flatfield import build_flatfield
from core.imaging.grid_detection import detect_grid_points
from core.imaging.pipeline import DarkStep, DeblurStep, FlatfieldStep, Pipeline, UndistortStep
from core.imaging.psf import gaussian_psf
from core.synthetic import (
    Distortion,
    ImagingModel,
    bead_lattice_frame,
    distortion_grid_frame,
    flatfield_frames,
    foot_rig,
)


@pytest.fixture(scope="module")
def setup():
    """A 512² view with the thesis-like chain: flatfield, distortion model, a few lattice frames."""
    cam = foot_rig(seed=0, pixels=512)[0]
    d = Distortion.for_camera(cam, k1=0.04, k2=0.06, twist_deg=5.0, twist_power=4.0)
    model = ImagingModel.fluoroscope(cam, rng=0, distortion=d)
    ff = build_flatfield(flatfield_frames(cam, model, 16, rng=1)[0], dark=model.dark_dn, kv=70)
    cal = calibrate_distortion(distortion_grid_frame(cam, model, rng=2).image, pitch_mm=15.0,
                               feature_diameter_px=3.0 / cam.pixel_size, model="poly(6,6)")
    offsets = ((-45.0, 40.0), (40.0, -40.0), (0.0, 0.0), (45.0, 45.0))  # towards the distorted rim
    frames = [bead_lattice_frame(cam, model, rng=10 + k, offset_mm=off, angle_rad=0.1 * k)
              for k, off in enumerate(offsets)]
    return cam, model, ff, cal, frames


def test_standard_chain_corrects_a_frame(setup, similarity_residual):
    cam, model, ff, cal, frames = setup
    pipe = Pipeline.standard(flatfield=ff, psf=gaussian_psf(model.psf_sigma_px), iterations=5,
                             distortion=cal.model)
    assert [s.kind for s in pipe.steps] == ["dark", "flatfield", "deblur", "undistort"]
    fr = frames[0]
    out = pipe.apply(fr.image)
    assert out.dtype == np.float32 and out.shape == (512, 512) and 0 <= out.min() and out.max() <= 1
    # the PMMA plate around the beads reads its transmission everywhere (roll-off gone)
    v, u = np.mgrid[0:512, 0:512]
    near = np.hypot(u - 256, v - 256) < 60
    far = (np.hypot(u - 256, v - 256) > 180) & (np.hypot(u - 256, v - 256) < 230)
    assert np.median(out[near]) == pytest.approx(np.median(out[far]), abs=0.02)
    # beads land on a straight lattice: corrected positions are a similarity of the truth
    from scipy.spatial import cKDTree

    pts = detect_grid_points(out, feature_diameter_px=2.0 / cam.pixel_size, polarity="dark")
    dist, idx = cKDTree(pts.uv).query(cal.model.inverse(fr.distorted_uv))
    assert dist.max() < 1.0  # every bead found where the model puts it
    got = pts.uv[idx]
    w = fr.ideal_uv[:, 0] + 1j * fr.ideal_uv[:, 1]
    z = got[:, 0] + 1j * got[:, 1]
    A = np.column_stack([w, np.ones_like(w)])
    assert np.abs(A @ np.linalg.lstsq(A, z, rcond=None)[0] - z).max() < 0.5
    raw = detect_grid_points(fr.image, feature_diameter_px=2.0 / cam.pixel_size, polarity="dark")
    zr = raw.uv[cKDTree(raw.uv).query(fr.distorted_uv)[1]]
    zr = zr[:, 0] + 1j * zr[:, 1]
    assert np.abs(A @ np.linalg.lstsq(A, zr, rcond=None)[0] - zr).max() > 2.0  # raw is distorted


def test_map_is_lazy_ordered_parallel_and_cancellable(setup):
    _, _, ff, cal, frames = setup
    pipe = Pipeline.standard(flatfield=ff, distortion=cal.model)
    pipe.prepare((512, 512))
    imgs = [f.image for f in frames]
    serial = [pipe.apply(x) for x in imgs]
    seen = []
    out = list(pipe.map(imgs, workers=2, progress=lambda d, n: seen.append((d, n))))
    for a, b in zip(out, serial, strict=True):
        np.testing.assert_array_equal(a, b)
    assert seen == [(1, 4), (2, 4), (3, 4), (4, 4)]
    pulled = []

    def source():  # a reader: frames are produced only when asked for
        for k in range(100):
            pulled.append(k)
            yield imgs[k % 4]

    stop = threading.Event()
    got = []
    run = pipe.run(source(), lambda i, f: (got.append(i), stop.set() if i == 2 else None), workers=2,
                   cancel=stop.is_set)
    assert run.cancelled and run.n_done == 3 and got == [0, 1, 2] and run.n_total is None
    assert len(pulled) <= 3 + 4  # read ahead by at most 2 x workers
    full = pipe.run(imgs, lambda i, f: None)
    assert not full.cancelled and full.n_done == full.n_total == 4


def test_parameters_round_trip_through_json(setup):
    _, model, ff, cal, frames = setup
    pipe = Pipeline((DarkStep(model.dark_dn), FlatfieldStep(ff),
                     DeblurStep(gaussian_psf(1.2), iterations=3, damping=1.0, photons_per_unit=400.0),
                     UndistortStep(cal.model, interpolation="cubic")))
    text = pipe.to_json()
    back = Pipeline.from_json(text)
    assert json.loads(back.to_json()) == json.loads(text)
    np.testing.assert_array_equal(back.apply(frames[1].image), pipe.apply(frames[1].image))
    # a store can keep arrays in its own files
    store = {}

    def enc(a):
        store[f"a{len(store)}"] = a
        return {"ref": f"a{len(store) - 1}"}

    d = pipe.to_dict(array_encoder=enc)
    assert len(json.dumps(d)) < 0.1 * len(text) and len(store) == 2  # the flatfield and the PSF
    again = Pipeline.from_dict(d, array_decoder=lambda r: store[r["ref"]])
    np.testing.assert_array_equal(again.apply(frames[1].image), pipe.apply(frames[1].image))


def test_bad_input_is_named(setup):
    _, _, ff, _, _ = setup
    with pytest.raises(ValueError, match="DarkStep"):
        Pipeline((FlatfieldStep(ff),))
    with pytest.raises(ValueError, match=r"steps\[0\]"):
        Pipeline(("flatfield",))
    with pytest.raises(ValueError, match="unknown step kind"):
        Pipeline.from_dict({"type": "imaging_pipeline", "version": 1, "steps": [{"kind": "sharpen"}]})
    with pytest.raises(ValueError, match="newer"):
        Pipeline.from_dict({"type": "imaging_pipeline", "version": 99, "steps": []})
    with pytest.raises(ValueError, match="frame"):
        Pipeline.standard(flatfield=ff).apply(np.zeros((2, 512, 512)))
    with pytest.raises(ValueError, match="workers"):
        next(Pipeline().map([np.zeros((4, 4))], workers=0))
