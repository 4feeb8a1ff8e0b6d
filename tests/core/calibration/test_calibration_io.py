"""Talus calibration file (versioned JSON), MayaCam 1.0/2.0 and DLT CSV interop."""

import json

import numpy as np
import pytest

from core.calibration.bundle import bundle_adjust
from core.calibration.io import (
    export_rig,
    load_calibration,
    read_dlt_csv_rig,
    read_mayacam_rig,
    save_calibration,
)
from core.calibration.objects import spiral_target
from core.synthetic.capture import capture_poses, observe


@pytest.fixture(scope="module")
def result(rig, sizes):
    tg = spiral_target(23)
    poses = capture_poses(rig, tg, 5, rng=1)
    return bundle_adjust(observe(rig, tg, poses, noise_px=0.05, rng=2), sizes, T_lab_from_reference=poses[0],
                         pixel_size=rig[0].pixel_size, pixel_sigma=0.05)


def _same_rig(a, b, atol=1e-9):
    for c, d in zip(a, b, strict=True):
        np.testing.assert_allclose(c.K, d.K, rtol=atol, atol=atol * 1e3)
        np.testing.assert_allclose(c.R, d.R, atol=atol)
        np.testing.assert_allclose(c.t, d.t, rtol=atol, atol=atol * 1e3)
        assert (c.width, c.height) == (d.width, d.height)


def test_talus_file_round_trip_with_uncertainties(tmp_path, result):
    p = tmp_path / "cal.json"
    save_calibration(p, result, metadata={"session": "2025-03-01", "operator": "lab"})
    back = load_calibration(p)
    _same_rig(back.rig, result.rig, atol=1e-12)
    assert back.version == 1 and back.metadata["operator"] == "lab"
    assert back.std[1]["f_px"] == pytest.approx(result.camera_std[1]["f"])
    assert back.std[0]["sid_mm"] == pytest.approx(result.camera_std[0]["sid"])
    assert back.quality["n_frames"] == 5 and back.quality["rms_px"] == pytest.approx(result.rms_px)
    doc = json.loads(p.read_text())
    assert doc["units"] == {"length": "mm", "angle": "rad", "image": "px"}
    assert doc["cameras"][0]["sid_mm"] == pytest.approx(result.rig[0].sid)
    save_calibration(tmp_path / "rig.json", result.rig)
    assert load_calibration(tmp_path / "rig.json").std == [{}, {}]


def test_talus_file_errors(tmp_path, result):
    p = tmp_path / "cal.json"
    save_calibration(p, result)
    doc = json.loads(p.read_text())
    p.write_text(json.dumps({**doc, "version": 7}))
    with pytest.raises(ValueError, match="newer Talus"):
        load_calibration(p)
    p.write_text(json.dumps({**doc, "format": "other"}))
    with pytest.raises(ValueError, match="format"):
        load_calibration(p)
    bad = json.loads(json.dumps(doc))
    bad["cameras"][0]["R"] = [[1, 0, 0], [0, 1, 0], [0, 0, 2]]
    p.write_text(json.dumps(bad))
    with pytest.raises(ValueError, match=r"cameras\[0\].*R"):
        load_calibration(p)
    p.write_text("{not json")
    with pytest.raises(ValueError, match="JSON"):
        load_calibration(p)
    with pytest.raises(ValueError, match="no such"):
        load_calibration(tmp_path / "none.json")
    failed = bundle_adjust([result_frames_without_view2()], [(64, 64), (64, 64)])
    with pytest.raises(ValueError, match="failed"):
        save_calibration(tmp_path / "x.json", failed)


def result_frames_without_view2():
    from core.calibration.bundle import ObjectFrame

    uv = np.full((2, 6, 2), np.nan)
    uv[0] = np.random.default_rng(0).uniform(0, 60, (6, 2))
    return ObjectFrame(np.random.default_rng(1).normal(size=(6, 3)), uv)


def test_export_to_mayacam_and_dlt_and_back(tmp_path, result, rig):
    paths = export_rig(result, tmp_path / "out", stem="day1")
    assert set(paths) == {"talus", "mayacam2", "mayacam1", "dlt"}
    _same_rig(read_mayacam_rig(paths["mayacam2"]), result.rig, atol=1e-12)
    m1 = read_mayacam_rig(paths["mayacam1"])  # one focal length, angles: ~1e-12
    _same_rig(m1, result.rig, atol=1e-8)
    dlt = read_dlt_csv_rig(paths["dlt"][0], [(c.width, c.height) for c in rig], pixel_size=rig[0].pixel_size)
    for c, d in zip(dlt, result.rig, strict=True):
        np.testing.assert_allclose(c.source, d.source, atol=1e-6)
        assert c.fx == pytest.approx(d.fx, rel=1e-9)
    with pytest.raises(ValueError, match="formats"):
        export_rig(result, tmp_path, formats=["vrml"])


def test_real_wrist_mayacam_through_the_talus_file(tmp_path, sample_data):
    folder = sample_data / "autoscoper_wrist" / "Calibration"
    if not folder.is_dir():
        pytest.skip(reason=f"wrist calibration not found at {folder}")
    rig = read_mayacam_rig([folder / f"xr_calib_wrist_cam0{k}.txt" for k in (1, 2)])
    save_calibration(tmp_path / "wrist.json", rig, metadata={"source": "Autoscoper sample"})
    back = load_calibration(tmp_path / "wrist.json").rig
    _same_rig(back, rig, atol=1e-12)
    assert back[0].name == "xr_calib_wrist_cam01"
