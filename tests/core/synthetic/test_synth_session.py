"""The synthetic calibration session (core.synthetic.session) against its own ground truth."""

import json

import numpy as np
import pytest
import tifffile

from core.imaging.grid_detection import detect_grid_points
from core.io.calibration_session import read_session
from core.synthetic.calib_objects import calibration_cube, helical_spiral
from core.synthetic.calibration import object_line_integrals
from core.synthetic.scene import make_foot_scene
from core.synthetic.session import _default_setup, spiral_poses, write_calibration_session

SMALL = {"pixels": 128, "n_spiral": 4, "n_grid": 2, "n_lattice": 1, "n_dark": 2, "n_flat": 3}


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    out = tmp_path_factory.mktemp("session") / "calibration_session"
    manifest = write_calibration_session(out, seed=3, kvs=(70, 75), **SMALL)
    return out, manifest


def test_layout_and_manifest_round_trip(small):
    out, manifest = small
    assert json.loads((out / "session.json").read_text()) == manifest
    assert manifest["format"] == "talus-calibration-session" and manifest["version"] == 1
    assert manifest["cameras"] == ["cam1", "cam2"] and manifest["bit_depth"] == 12
    assert manifest["frame_size"] == [128, 128]
    assert manifest["groups"] == {"dark": "dark", "flat": {"70": "flat_70kV", "75": "flat_75kV"},
                                  "grid": "grid", "cube": "cube", "spiral": "spiral",
                                  "lattice": "lattice", "glare": "glare"}
    assert manifest["grid"]["kind"] == "hole" and manifest["grid"]["pitch_mm"] == 15.0
    assert manifest["objects"] == {"cube": "cube15", "spiral": "spiral33"}
    s = read_session(out)
    assert s.cameras == ("cam1", "cam2") and s.frame_size == (128, 128) and s.kvs == (70.0, 75.0)
    for cam in s.cameras:
        counts = {g: len(s.frames(cam, g)) for g in ("dark", "flat:70", "flat:75", "grid", "lattice",
                                                     "glare", "cube", "spiral")}
        assert counts == {"dark": 2, "flat:70": 3, "flat:75": 3, "grid": 2, "lattice": 1, "glare": 2,
                          "cube": 1, "spiral": 4}
        p = s.frames(cam, "spiral")[2]
        assert p == out / cam / "spiral" / "0002.tif"
        raw = tifffile.imread(p)
        assert raw.dtype == np.uint16 and raw.max() <= 4095
        np.testing.assert_array_equal(s.read(p), raw.astype(np.float32))
    assert not list(out.parent.glob(".*tmp"))  # the temporary folder was renamed into place


def test_frames_follow_the_image_chain(small):
    out, _ = small
    s = read_session(out)
    truth = np.load(out / "truth" / "truth.npz")
    meta = json.loads((out / "truth" / "truth.json").read_text())
    rig, models, floor = _default_setup(128, 3, 60.0)
    for v, cam in enumerate(s.cameras):
        m = models[v]
        assert meta["imaging"][cam] == m.to_dict()
        np.testing.assert_allclose(meta["cameras"][v]["K"], rig[v].K)
        dark = s.stack(cam, "dark")
        assert abs(dark.mean() - m.dark_dn) < 0.1 and abs(dark.std() - m.read_noise_dn) < 0.2
        flat = s.stack(cam, "flat:70").mean(axis=0)
        true_flat = truth[f"flatfield_{cam}_70kV"]
        np.testing.assert_allclose(true_flat, m.flatfield((128, 128)), rtol=1e-6)
        inside = true_flat > m.dark_dn + 0.5 * m.gain_dn
        # three frames of ~0.5 quanta-limited noise: the mean follows the noise-free flatfield
        rel = (flat - true_flat)[inside] / (true_flat[inside] - m.dark_dn)
        assert abs(rel.mean()) < 0.005 and rel.std() < 0.06
        hi = s.stack(cam, "flat:75").mean(axis=0)
        ratio = np.median((hi - m.dark_dn)[inside] / (flat - m.dark_dn)[inside])
        assert ratio == pytest.approx((75 / 70) ** 2, rel=0.01)
        # the cube frame is the chain's noisy rendering of the cube over the walkway
        from core.synthetic.analytic import slab_line_integrals

        L = object_line_integrals(rig[v], calibration_cube(), np.eye(4)) + slab_line_integrals(
            rig[v], (0.0, 0.0, floor[0] - floor[1] / 2), (0.0, 0.0, 1.0), floor[1], floor[2])
        expected = m.expected_dn(L)
        cube = s.read(s.frames(cam, "cube")[0])
        ok = expected > m.dark_dn + 0.1 * m.gain_dn
        z = (cube - expected)[ok] / np.sqrt(m.gain_dn * (expected[ok] - m.dark_dn) / m.photons_per_pixel
                                            + m.read_noise_dn**2 + 1)
        assert abs(z.mean()) < 0.1 and z.std() < 1.5


def test_spiral_poses_cover_the_capture_volume(small):
    out, _ = small
    truth = np.load(out / "truth" / "truth.npz")
    rig, models, _ = _default_setup(128, 3, 60.0)
    uv = truth["spiral_distorted_uv"]  # (frame, view, bead, 2)
    assert uv.shape == (4, 2, 33, 2)
    for v, m in enumerate(models):
        r = np.hypot(*(uv[:, v] - np.array(m.distortion.center)).transpose(2, 0, 1))
        assert r.max() < m.aperture_radius * 64  # every bead inside the round field
    poses = spiral_poses(rig, models, 40, rng=0)
    spiral = helical_spiral(33)
    centres = poses[:, :3, 3]
    axes = poses[:, :3, 2]
    beads = np.concatenate([spiral.centers_lab(T) for T in poses])
    assert np.all(centres.std(axis=0) > 10.0)  # spread in every direction, mm
    assert np.all(np.ptp(beads, axis=0) > 150.0)  # the beads fill the volume
    # varied orientations: the long axes scatter (largest eigenvalue of their scatter matrix:
    # 1 when parallel, 1/3 when uniform on the sphere; pairs typically 50 degrees apart)
    assert np.linalg.eigvalsh(axes.T @ axes / len(axes))[-1] < 0.7
    ang = np.degrees(np.arccos(np.clip(np.abs(axes @ axes.T), 0.0, 1.0)))
    assert np.median(ang[np.triu_indices(len(axes), 1)]) > 35.0
    assert np.all(beads[:, 2] > -85.0)  # above the walkway


def test_grid_frames_are_detectable(tmp_path):
    out = tmp_path / "s"
    write_calibration_session(out, pixels=384, seed=1, n_spiral=1, n_grid=3, n_lattice=0, n_dark=1,
                              n_flat=1)
    s = read_session(out)
    truth = np.load(out / "truth" / "truth.npz")
    px = 300.0 / 384
    for cam in s.cameras:
        pts = detect_grid_points(s.stack(cam, "grid"), feature_diameter_px=3.0 / px)
        true = truth[f"grid_{cam}_distorted_uv"]
        d = np.linalg.norm(pts.uv[:, None] - true[None], axis=2)
        near = d.min(axis=1)
        assert np.median(near) < 0.2 and np.mean(near < 1.0) > 0.95
        assert np.sum(d.min(axis=0) < 1.0) > 0.8 * len(true)  # most holes found


def test_same_rig_and_chain_as_the_demo_scene(tmp_path):
    scene = make_foot_scene(n_frames=1, pixels=64, spacing=4.0, tissue_spacing=8.0, seed=2)
    rig, models, floor = _default_setup(64, 2, 60.0)
    assert floor == scene.floor
    for a, b, ma, mb in zip(rig, scene.rig, models, scene.imaging, strict=True):
        np.testing.assert_array_equal(a.K, b.K)
        np.testing.assert_array_equal(a.R, b.R)
        assert ma.to_dict() == mb.to_dict()
    m = write_calibration_session(tmp_path / "s", scene=scene, seed=2, n_spiral=1, n_grid=1,
                                  n_lattice=0, n_dark=1, n_flat=1)
    assert m["frame_size"] == [64, 64]
    with pytest.raises(ValueError, match="pixels"):
        write_calibration_session(tmp_path / "t", scene=scene, pixels=128)


def test_cancel_keeps_the_earlier_session(tmp_path):
    out = tmp_path / "s"
    opts = dict(pixels=64, n_spiral=2, n_grid=1, n_lattice=0, n_dark=1, n_flat=1, n_glare=0)
    write_calibration_session(out, seed=0, **opts)
    before = (out / "session.json").read_bytes()
    calls = []
    assert write_calibration_session(out, seed=5, cancel=lambda: len(calls) > 2,
                                     progress=lambda d, n: calls.append((d, n)), **opts) is None
    assert (out / "session.json").read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s"]
    m = write_calibration_session(out, seed=5, **opts)
    assert calls[-1][1] == 1 + 1 + 1 + 1 + 2 and json.loads((out / "session.json").read_text()) == m


def test_bad_arguments(tmp_path):
    (tmp_path / "file").write_text("x")
    with pytest.raises(ValueError, match="not a folder"):
        write_calibration_session(tmp_path / "file", pixels=64)
    with pytest.raises(ValueError, match="n_spiral"):
        write_calibration_session(tmp_path / "s", pixels=64, n_spiral=0)
    with pytest.raises(ValueError, match="cameras"):
        write_calibration_session(tmp_path / "s", pixels=64, cameras=("a", "a"))
    with pytest.raises(ValueError, match="kvs"):
        write_calibration_session(tmp_path / "s", pixels=64, kvs=(70, 120))
    assert not (tmp_path / "s").exists()


@pytest.mark.parametrize("pixels", [160, 512])
def test_spiral_renderer_matches_the_analytic_integrals(pixels):
    from core.synthetic.analytic import bead_line_integrals, cylinder_line_integrals
    from core.synthetic.session import _ObjectRenderer

    rig, models, _ = _default_setup(pixels, 0, 60.0)
    spiral = helical_spiral(33)
    T = spiral_poses(rig, models, 1, rng=4)[0]
    r = _ObjectRenderer(rig[1], spiral)
    _, radius, half, mu_core, wall, mu_wall = spiral.body
    body = cylinder_line_integrals(rig[1], np.stack([T, T]), [radius, radius - wall], half,
                                   [mu_wall, mu_core - mu_wall], supersample=1)
    err = np.abs(r.body(T) - body)
    if pixels < 512:
        np.testing.assert_allclose(r.body(T), body, atol=1e-5)
        beads = bead_line_integrals(rig[1], spiral.centers_lab(T), spiral.diameters,
                                    spiral.bead_mu - mu_core, average="fluence")
        np.testing.assert_allclose(r.beads(T), beads, atol=1e-5)
    else:  # sampled on 2 x 2 blocks: off only along the tube's edges
        assert r.block == 2
        assert err.mean() < 0.003 * body.max() and np.mean(err > 0.05 * body.max()) < 0.01
