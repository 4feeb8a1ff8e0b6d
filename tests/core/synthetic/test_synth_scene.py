"""Scene rendering (Warp CPU and numpy reference) and the demo study writer, on tiny sizes."""

import json
from dataclasses import replace

import numpy as np
import pytest
import tifffile

from core.geometry import read_mayacam
from core.io import read_tiff_volume
from core.render import HUTransfer
from core.synthetic.demo import make_demo_study
from core.synthetic.imaging import ImagingModel
from core.synthetic.scene import BeadSet, BiplaneScene, excess_transfer, make_foot_scene


@pytest.fixture(scope="module")
def tiny_scene():
    # 64^2 detectors, <= 48^3 volumes (4 mm voxels), 3 frames
    return make_foot_scene(n_frames=3, pixels=64, spacing=4.0, tissue_spacing=8.0, seed=1)


def test_excess_transfer_counts_tissue_once():
    base = HUTransfer(mu_water=0.0206)
    ex = excess_transfer(base, 40.0)
    hu = np.array([-1000.0, 0.0, 30.0, 40.0, 300.0, 1500.0, 3000.0])
    np.testing.assert_allclose(ex(hu), np.maximum(base(hu) - base(np.array([40.0]))[0], 0), atol=1e-7)
    assert ex(np.array([40.0]))[0] == 0.0
    hu = np.linspace(-1000.0, 3000.0, 801)
    for tr in (HUTransfer(bone_slope=1.6), HUTransfer(curve=((-1000, 0, 500, 3000), (0, 0.02, 0.04, 0.09)))):
        want = np.maximum(tr(hu) - tr(np.array([40.0]))[0], 0.0)
        np.testing.assert_allclose(excess_transfer(tr)(hu), want, atol=1e-7)


def test_scene_volumes_are_small(tiny_scene):
    assert all(max(b.data.shape) <= 48 for b in tiny_scene.bones)
    assert tiny_scene.n_frames == 3 and tiny_scene.rig[0].image_shape == (64, 64)
    assert len(tiny_scene.tissue) == 2 and tiny_scene.floor is not None


def test_warp_and_reference_renderers_agree(tiny_scene):
    Lw = tiny_scene.renderer(device="cpu").volume_integrals(1)
    Lr = tiny_scene.renderer(backend="reference").volume_integrals(1)
    assert Lw.shape == (2, 64, 64) and Lw.dtype == np.float32
    np.testing.assert_allclose(Lw, Lr, rtol=1e-3, atol=1e-4)
    assert Lw.max() > 1.0  # a foot attenuates


def test_render_frame_is_deterministic_per_frame(tiny_scene):
    r = tiny_scene.renderer(device="cpu")
    a = tiny_scene.render_frame(2, renderer=r)
    tiny_scene.render_frame(0, renderer=r)
    b = tiny_scene.render_frame(2, renderer=r)
    assert a.shape == (2, 64, 64) and a.dtype == np.uint16 and a.max() <= 4095
    np.testing.assert_array_equal(a, b)
    again = make_foot_scene(n_frames=3, pixels=64, spacing=4.0, tissue_spacing=8.0, seed=1)
    np.testing.assert_array_equal(again.render_frame(2, renderer=again.renderer(device="cpu")), a)
    assert np.any(tiny_scene.render_frame(1, renderer=r) != a)  # the foot moves, noise differs


def test_beads_image_at_their_ground_truth_positions():
    sc = make_foot_scene(n_frames=2, pixels=128, spacing=4.0, tissue_spacing=8.0, seed=2,
                         bead_diameter_mm=8.0, beads_per_bone=2, imaging="ideal", soft_tissue=False,
                         names=("talus", "calcaneus"))
    r = sc.renderer(backend="reference")
    with_beads = sc.line_integrals(1, renderer=r)
    bare = replace(sc, beads=())
    without = bare.line_integrals(1, renderer=bare.renderer(backend="reference"))
    with pytest.raises(ValueError, match="renderer"):
        bare.line_integrals(1, renderer=r)  # another scene's renderer
    bead_img = with_beads - without
    uv = sc.bead_uv(1, distorted=False)
    for v in range(2):
        for q in uv[v]:
            u0, v0 = np.rint(q).astype(int)
            win = bead_img[v, v0 - 5 : v0 + 6, u0 - 5 : u0 + 6].astype(float)
            if win.shape != (11, 11):
                continue
            vv, uu = np.mgrid[v0 - 5 : v0 + 6, u0 - 5 : u0 + 6]
            cen = np.array([(uu * win).sum(), (vv * win).sum()]) / win.sum()
            assert np.linalg.norm(cen - q) < 0.15  # overlapping beads would bias; none here
    c, d, mu = sc.bead_positions(0)
    assert c.shape == (4, 3) and np.all(d == 8.0) and np.all(mu > 0.9)


def test_scene_validation(tiny_scene):
    with pytest.raises(ValueError, match="trajectories"):
        replace(tiny_scene, trajectories=tiny_scene.trajectories[:2])
    with pytest.raises(ValueError, match="imaging"):
        replace(tiny_scene, imaging=(ImagingModel(),))
    with pytest.raises(ValueError, match="beads"):
        replace(tiny_scene, beads=(BeadSet(np.zeros((1, 3)), [2.0], 9, 1.0),))
    with pytest.raises(ValueError, match="i:"):
        tiny_scene.poses(3)
    assert isinstance(tiny_scene, BiplaneScene)


def test_demo_study_files_and_ground_truth(tmp_path):
    calls = []
    s = make_demo_study(tmp_path / "study", n_frames=2, pixels=64, seed=3, device="cpu",
                        spacing=4.0, tissue_spacing=8.0,
                        progress=lambda i, n, *stage: calls.append((i, n, *stage)))
    out = tmp_path / "study"
    assert s["status"] == "complete" and s["frames_written"] == 2 and calls[:2] == [(1, 2), (2, 2)]
    # then the calibration session beside the trial, of the same rig and image chains
    assert calls[-1] == (68, 68, "calibration session") and len(calls) == 2 + 68  # 2 of them the glare disc's
    assert s["calibration_session"] == "calibration_session"
    from core.io import read_session

    session = read_session(out / "calibration_session")
    assert session.frame_size == (64, 64) and len(session.frames("cam2", "spiral")) == 40
    truth = json.loads((out / "calibration_session" / "truth" / "truth.json").read_text())
    assert [c["rig_name"] for c in truth["cameras"]] == ["cam01", "cam02"]
    assert truth["imaging"]["cam1"] == json.loads((out / "imaging" / "cam01.json").read_text())
    assert (out / "summary.json").is_file()
    assert not list(out.rglob("*.tmp"))
    sc = make_foot_scene(n_frames=2, pixels=64, seed=3, spacing=4.0, tissue_spacing=8.0)
    for v, cam in enumerate(sc.rig):
        back = read_mayacam(out / "rig" / f"{cam.name}.txt", pixel_size=cam.pixel_size)
        np.testing.assert_allclose(back.P, cam.P, rtol=1e-12, atol=1e-9)
        frame = tifffile.imread(out / "frames" / cam.name / "frame_0001.tif")
        assert frame.dtype == np.uint16 and frame.shape == (64, 64) and frame.max() <= 4095
        np.testing.assert_array_equal(frame, sc.render_frame(1, renderer=sc.renderer(device="cpu"))[v])
        uv = np.load(out / "beads" / f"uv_{cam.name}.npy")
        np.testing.assert_allclose(uv[1], sc.bead_uv(1)[v])
    np.testing.assert_array_equal(np.load(out / "poses" / "all.npy"), sc.trajectories)
    beads = np.loadtxt(out / "beads" / "beads.csv", delimiter=",", skiprows=1,
                       usecols=(0, 2, 3, 4, 5))
    assert beads.ndim == 2 and beads.shape[1] == 5 and np.all(np.isfinite(beads))
    assert np.all((beads[:, 4] > 0.5) & (beads[:, 4] < 10))  # diameters, mm
    np.testing.assert_array_equal(beads[:, 1:4], np.concatenate([b.centers for b in sc.beads]))
    rows = np.loadtxt(out / "poses" / "talus.csv", delimiter=",", skiprows=1)
    np.testing.assert_allclose(rows[:, 1:].reshape(-1, 4, 4), sc.trajectories[1])
    # the folder is also a study: rig, bones (MetaImage keeps the geometry), trial, keyframe 0
    from core.study import Study

    with Study.open(out) as st:
        trial = st.trial("walk")
        assert trial.n_frames == 2 and st.bones == tuple(sc.names)
        np.testing.assert_allclose(trial.rig()[0].P, sc.rig[0].P, rtol=1e-12, atol=1e-9)
        talus = st.bone_volume("talus")
        np.testing.assert_array_equal(talus.data, sc.bones[1].data)
        np.testing.assert_allclose(talus.origin, sc.bones[1].origin)
        np.testing.assert_allclose(talus.spacing, sc.bones[1].spacing)
        np.testing.assert_allclose(trial.poses("talus")[0], sc.trajectories[1][0])
        assert np.isnan(trial.poses("talus")[1]).all()
        np.testing.assert_array_equal(trial.frames(1)[0], tifffile.imread(
            out / "frames" / sc.rig[0].name / "frame_0001.tif"))
    meta = json.loads((out / "volumes" / "talus.json").read_text())
    vol = read_tiff_volume(out / "volumes" / "talus.tif", meta["spacing"], origin=meta["origin"])
    np.testing.assert_array_equal(vol.data, sc.bones[1].data)
    np.testing.assert_allclose(vol.origin, sc.bones[1].origin)


def test_demo_study_cancel(tmp_path):
    state = {"n": 0}

    def cancel():
        state["n"] += 1
        return state["n"] > 1  # allow the first frame only

    s = make_demo_study(tmp_path, n_frames=3, pixels=64, device="cpu", spacing=4.0,
                        tissue_spacing=8.0, cancel=cancel)
    assert s["status"] == "cancelled" and s["frames_written"] == 1
    assert len(list((tmp_path / "frames" / "cam01").glob("*.tif"))) == 1
    assert s["calibration_session"] is None and not (tmp_path / "calibration_session").exists()
    with pytest.raises(ValueError, match="out_dir"):
        make_demo_study(tmp_path / "summary.json", n_frames=1, pixels=64, spacing=4.0)
