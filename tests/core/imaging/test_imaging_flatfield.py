"""Flatfield estimation and normalisation against the synthetic roll-off (thesis §3.3)."""

import json

import numpy as np
import pytest

from core.imaging.flatfield import Flatfield, FlatfieldLibrary, build_flatfield
from core.synthetic import ImagingModel, flatfield_frames, foot_rig


@pytest.fixture(scope="module")
def cam512():
    return foot_rig(seed=0, pixels=512)[0]


@pytest.fixture(scope="module")
def flat_data(cam512):
    model = ImagingModel.fluoroscope(cam512, rng=0)
    frames, truth = flatfield_frames(cam512, model, 16, rng=1)
    return model, frames, truth


def _residual(truth, model, ff):
    """(p99 - p1, max - min) of the noise-free true flatfield after normalisation."""
    r = (truth - model.dark_dn) / ff.gain
    return np.percentile(r, 99) - np.percentile(r, 1), r.max() - r.min()


@pytest.mark.parametrize("method", ["max", "mean", "median", "polynomial", "spline"])
def test_residual_rolloff_below_two_percent(flat_data, method):
    model, frames, truth = flat_data
    raw = (truth - model.dark_dn) / (truth.max() - model.dark_dn)
    assert raw.min() < 0.5  # the uncorrected field rolls off by more than half in the corners
    ff = build_flatfield(frames, dark=model.dark_dn, method=method, kernel_size=15)
    spread, full = _residual(truth, model, ff)
    assert spread < 0.02 and full < 0.025, (spread, full)
    assert ff.n_frames == 16 and ff.gain.dtype == np.float32


def test_max_surface_follows_the_upper_envelope(flat_data):
    model, frames, _ = flat_data
    one = build_flatfield(frames[:1], dark=model.dark_dn, method="max", kernel_size=15)
    mean = build_flatfield(frames[:1], dark=model.dark_dn, method="mean", kernel_size=15)
    assert np.median(one.gain / mean.gain) > 1.005  # the max kernel sits above the mean
    # an empty frame normalised by the max flatfield reads just below 1
    ff = build_flatfield(frames, dark=model.dark_dn, method="max", kernel_size=15)
    out = ff.normalise(frames[0])
    assert out.dtype == np.float32 and 0 <= out.min() and out.max() <= 1
    assert 0.96 < np.median(out) < 1.0


def test_normalised_trial_frame_matches_ground_truth(flat_data, cam512):
    model, frames, _ = flat_data
    ff = build_flatfield(frames, dark=model.dark_dn, method="max", kernel_size=15)
    v, u = np.mgrid[0:512, 0:512]
    L = 0.8 * (np.hypot(u - 300, v - 200) < 120)  # a disc of attenuation in the field
    frame = model.apply(L, rng=5)
    got, want = ff.normalise(frame), model.to_float(frame)
    assert np.median(np.abs(got - want)) < 0.01
    inside = np.hypot(u - 300, v - 200) < 100
    assert np.mean(got[inside]) == pytest.approx(np.exp(-0.8), abs=0.02)


def test_surface_fit_masks_hardware(cam512):
    model = ImagingModel.fluoroscope(cam512, rng=0)
    v, u = np.mgrid[0:512, 0:512]
    gauge = (np.abs(u - 330) < 40) & (np.abs(v - 260) < 12)  # a strain gauge in the walkway
    frames, _ = flatfield_frames(cam512, model, 16, rng=2, background=np.where(gauge, 1.0, 0.0))
    empty = model.flatfield((512, 512))  # the roll-off alone is what must be divided out
    bad = build_flatfield(frames, dark=model.dark_dn, method="max", kernel_size=15)
    assert _residual(empty, model, bad)[1] > 0.5  # the max kernel copies the gauge's shadow
    for kw in ({"mask": (np.abs(u - 330) < 48) & (np.abs(v - 260) < 20)}, {}):
        ff = build_flatfield(frames, dark=model.dark_dn, method="spline", **kw)
        assert _residual(empty, model, ff)[0] < 0.02, kw  # masked, or rejected as an outlier


def test_zero_flatfield_pixels_are_guarded_and_reported(cam512):
    model = ImagingModel.fluoroscope(cam512, rng=0, aperture_radius=0.9, read_noise_dn=0.0)
    frames, _ = flatfield_frames(cam512, model, 4, rng=3)
    dark = np.full((2, 512, 512), model.dark_dn)
    ff = build_flatfield(frames, dark=dark, method="max", kernel_size=9)
    outside = ~ff.valid
    assert 0.37 * 512**2 > ff.n_invalid > 0.3 * 512**2  # the corners outside the round field (36 %)
    out = ff.normalise(frames[0])  # no division warnings (they would be errors here)
    assert np.all(out[outside] == 0) and np.isfinite(out).all()


def test_library_per_kv_and_serialisation(flat_data, cam512):
    model, frames, _ = flat_data
    f70 = build_flatfield(frames, dark=model.dark_dn, kv=70)
    m60 = ImagingModel.fluoroscope(cam512, rng=0, rolloff_edge=0.55)
    f60 = build_flatfield(flatfield_frames(cam512, m60, 4, rng=4)[0], dark=np.full((512, 512), 60.0), kv=60)
    lib = FlatfieldLibrary([f70, f60])
    assert lib.kvs == [60.0, 70.0] and lib[70] is f70 and lib.get(60.4) is f60
    with pytest.raises(ValueError, match=r"no flatfield for 65 kV.*\[60.0, 70.0\]"):
        lib.get(65)
    back = FlatfieldLibrary.from_dict(json.loads(json.dumps(lib.to_dict())))
    np.testing.assert_array_equal(back[60].gain, f60.gain)
    np.testing.assert_array_equal(back[60].dark, f60.dark)
    assert back[70].dark == model.dark_dn and back[70].method == "max"


def test_bad_input_is_named(flat_data):
    _, frames, _ = flat_data
    with pytest.raises(ValueError, match="method"):
        build_flatfield(frames, method="gaussian")
    with pytest.raises(ValueError, match="kernel_size"):
        build_flatfield(frames, kernel_size=16)
    with pytest.raises(ValueError, match="dark: expected frames of shape"):
        build_flatfield(frames, dark=np.zeros((10, 10)))
    with pytest.raises(ValueError, match="frames"):
        build_flatfield(np.zeros(5))
    with pytest.raises(ValueError, match=r"frame: expected shape \(512, 512\)"):
        Flatfield(np.ones((512, 512), np.float32)).normalise(np.zeros((4, 4)))
