"""The calibration comparison's noise controls: the resampled true corrections they track with."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
import tifffile

from core.studies.calibration.noise_controls import _field, resampled_true_correction
from core.studies.calibration.truth import true_correction
from core.synthetic.distortion import Distortion


@pytest.fixture()
def folder(tmp_path):
    """A demo folder's ``imaging/`` for one 64² view: a distortion, a dark level and a flatfield."""
    d = Distortion((32.3, 31.1), 32.0, 0.04, 0.0, float(np.radians(2.0)), 2.0)
    (tmp_path / "imaging").mkdir()
    (tmp_path / "imaging" / "cam01.json").write_text(json.dumps({"dark_dn": 60.0, "distortion": d.to_dict()}))
    v, u = np.mgrid[0:64, 0:64]
    flat = 60.0 + 3000.0 * (1.0 - 0.2 * ((u - 32) ** 2 + (v - 32) ** 2) / 32**2)
    tifffile.imwrite(tmp_path / "imaging" / "flatfield_cam01.tif", flat.astype(np.float32))
    return tmp_path


def _raw():
    v, u = np.mgrid[0:64, 0:64].astype(float)
    return (60.0 + 2000.0 * (1.0 + 0.5 * np.sin(u / 5.0) * np.cos(v / 7.0))).astype(np.uint16)


def test_without_a_shift_it_is_the_true_correction(folder):
    a = true_correction(folder, ["cam01"])[0](_raw())
    b = resampled_true_correction(folder, ["cam01"])[0](_raw())
    np.testing.assert_allclose(b, a, atol=1e-6)


def test_a_grid_shift_moves_the_corrected_image_by_it(folder):
    # the shifted rig's principal point moves by -delta: pixel p must show what p + delta showed
    delta = (0.3, -0.2)
    a = true_correction(folder, ["cam01"])[0](_raw())
    b = resampled_true_correction(folder, ["cam01"], grid_shift=delta)[0](_raw())
    v, u = np.mgrid[0:64, 0:64].astype(np.float32)
    a_at = cv2.remap(a, u + delta[0], v + delta[1], cv2.INTER_LINEAR)
    inner = (slice(8, 56), slice(8, 56))
    assert np.abs(b - a_at)[inner].mean() < 0.1 * np.abs(b - a)[inner].mean()


def test_the_displacement_field_has_the_asked_rms():
    mask = np.zeros((64, 64), bool)
    mask[10:50, 5:60] = True
    f = _field((64, 64), 0.045, 24.0, mask)
    assert f.shape == (64, 64, 2)
    assert np.sqrt(np.mean(np.sum(f[mask] ** 2, axis=-1))) == pytest.approx(0.045)
