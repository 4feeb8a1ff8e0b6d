"""DRR kernels against analytic line integrals and the independent numpy reference."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from core.geometry import Camera, Rig, make_K
from core.render import CTVolume, DRRRenderer, render_reference


def _rigid(rotvec, trans):
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(rotvec).as_matrix()
    T[:3, 3] = trans
    return T


def _camera(angle=0.0, pixels=48, f=1600.0, name="cam"):
    """Source 1000 mm from the origin, looking at it; 48² detector at 0.9 mm/px, SID 1440 mm."""
    ca, sa = np.cos(angle), np.sin(angle)
    R = np.array([[ca, 0.0, -sa], [0.0, 1.0, 0.0], [sa, 0.0, ca]])
    c = (pixels - 1) / 2
    return Camera(make_K(f, f, c + 0.3, c - 0.4), R, [0.0, 0.0, 1000.0], pixels, pixels,
                  pixel_size=0.9, name=name)


def _ball_volume(radius=8.0, n=24, spacing=1.0, mu=0.02, supersample=4):
    """Uniform ball with partial-volume voxels (supersampled occupancy)."""
    s = (np.arange(supersample) + 0.5) / supersample - 0.5
    idx = (np.arange(n) - (n - 1) / 2) * spacing
    occ = np.zeros((n, n, n))
    for dz in s:
        for dy in s:
            for dx in s:
                z, y, x = np.meshgrid(idx + dz * spacing, idx + dy * spacing, idx + dx * spacing,
                                      indexing="ij")
                occ += (x**2 + y**2 + z**2) <= radius**2
    data = (mu * occ / supersample**3).astype(np.float32)
    origin = -np.full(3, (n - 1) / 2 * spacing)
    return CTVolume(data, spacing=[spacing] * 3, origin=origin, units="1/mm", name="ball")


def _random_volume(seed, shape=(14, 17, 19), spacing=(0.9, 1.1, 1.3), sparse=False):
    rng = np.random.default_rng(seed)
    data = rng.random(shape).astype(np.float32) * 0.03
    if sparse:  # a small blob in an otherwise empty box: exercises empty-space skipping
        data[:] = 0
        data[3:7, 4:8, 8:12] = rng.random((4, 4, 4)) * 0.05
    D = Rotation.from_rotvec([0.2, -0.1, 0.3]).as_matrix()
    return CTVolume(data, spacing=spacing, origin=[-8.0, -9.0, -7.0], direction=D, units="1/mm")


@pytest.mark.parametrize("interpolation", ["trilinear", "texture"])
def test_ball_matches_analytic_chords(interpolation):
    mu, radius = 0.02, 8.0
    vol = _ball_volume(radius=radius, mu=mu)
    cam = _camera()
    r = DRRRenderer([cam], [vol], device="cpu", interpolation=interpolation, step_mm=0.25)
    img = r.render_full(np.eye(4)[None], 0)
    _, d = cam.rays(cam.pixel_grid())
    src = cam.source
    # distance from the ball centre (origin) to each ray
    perp = np.linalg.norm(np.cross(d, -src), axis=-1)
    chord = 2 * np.sqrt(np.clip(radius**2 - perp**2, 0, None)) * mu
    centre = perp < radius - 2  # away from the partial-volume rim
    rel = np.abs(img - chord)[centre] / (2 * radius * mu)
    # every ray crosses the partial-volume rim twice; its trilinear reconstruction is good to
    # ~0.1 voxel per crossing, i.e. ~1 % of a 16-voxel chord
    assert rel.max() < 0.02, rel.max()
    assert rel.mean() < 0.01, rel.mean()
    # the rim is blurred by one voxel, but the total projected "mass" is preserved
    assert abs(img.sum() - chord.sum()) / chord.sum() < 0.01


def test_trilinear_kernel_matches_reference_with_roi_scale_and_two_bones():
    cams = Rig((_camera(0.0, name="a"), _camera(np.deg2rad(75), name="b")))
    vols = [_random_volume(1), _random_volume(2, shape=(9, 11, 13), sparse=True)]
    poses = np.stack([_rigid([0.1, 0.2, -0.3], [1.0, -2.0, 3.0]), _rigid([-0.2, 0.0, 0.1], [2.0, 1.0, -1.0])])
    r = DRRRenderer(cams, vols, device="cpu", interpolation="trilinear", step_mm=0.7)
    roi = np.array([5, 7, 33, 29])
    batch = r.render(poses, roi=roi, scale=2.0)
    assert batch.shape == (1, 2, 2)
    for v in range(2):
        for n in range(2):
            got = batch.item(0, v, n)
            ref = render_reference(cams[v], vols[n], poses[n], step_mm=0.7, roi=tuple(roi), scale=2.0)
            assert got.shape == ref.shape == (15, 17)
            assert ref.max() > 0.1
            np.testing.assert_allclose(got, ref, atol=1e-4 * ref.max(), rtol=0)


@pytest.mark.parametrize(("texture_dtype", "tol"), [("float32", 1e-5), ("uint16", 2e-5), ("float16", 5e-4)])
def test_texture_path_close_to_exact(texture_dtype, tol):
    # Warp's CPU texture filter uses exact weights, so only the storage precision shows here;
    # CUDA's 8-bit filter weights are measured by `talus bench drr` ("texture_vs_exact").
    cam = _camera()
    vol = _random_volume(3)
    T = _rigid([0.3, -0.1, 0.2], [0.5, 0.5, -1.0])
    exact = DRRRenderer([cam], [vol], device="cpu", interpolation="trilinear").render_full(T[None], 0)
    tex = DRRRenderer(
        [cam], [vol], device="cpu", interpolation="texture", texture_dtype=texture_dtype
    ).render_full(T[None], 0)
    assert exact.max() > 0.1
    assert np.abs(tex - exact).max() < tol * exact.max()


def test_batch_items_equal_single_renders_and_roi_is_a_crop_of_full():
    cams = Rig((_camera(0.0), _camera(np.deg2rad(90))))
    vol = _random_volume(4)
    rng = np.random.default_rng(0)
    poses = np.stack([_rigid(rng.normal(0, 0.2, 3), rng.normal(0, 2, 3)) for _ in range(3)])[:, None]
    r = DRRRenderer(cams, [vol], device="cpu")
    full = r.render(poses, roi="full").numpy()  # (3, 2, 1, 48, 48)
    for b in range(3):
        single = r.render(poses[b], roi="full").numpy()[0]
        np.testing.assert_array_equal(single, full[b])
    auto = r.render(poses)  # projected bounding boxes
    for b in range(3):
        for v in range(2):
            u0, v0, w, h = auto.roi[b, v, 0]
            crop = auto.item(b, v, 0)
            np.testing.assert_allclose(crop, full[b, v, 0, v0 : v0 + h, u0 : u0 + w], atol=1e-6)
            # nothing of the bone falls outside its automatic ROI
            outside = full[b, v, 0].copy()
            outside[v0 : v0 + h, u0 : u0 + w] = 0
            assert outside.max() == 0


def test_rigid_motion_of_bone_and_rig_together_leaves_drr_unchanged():
    cam = _camera(0.4)
    vol = _random_volume(5)
    T = _rigid([0.1, -0.3, 0.2], [3.0, 1.0, -2.0])
    G = _rigid([0.5, 0.1, -0.4], [20.0, -15.0, 7.0])  # move the whole lab
    G_inv = np.linalg.inv(G)
    cam2 = Camera(cam.K, cam.R @ G_inv[:3, :3], cam.R @ G_inv[:3, 3] + cam.t, cam.width, cam.height)
    a = DRRRenderer([cam], [vol], device="cpu").render_full(T[None], 0)
    b = DRRRenderer([cam2], [vol], device="cpu").render_full((G @ T)[None], 0)
    # the sample grid is fixed to each ray, so only float32 rounding differs
    np.testing.assert_allclose(a, b, atol=2e-4 * a.max(), rtol=0)


@pytest.mark.parametrize("interpolation", ["trilinear", "texture"])
def test_drr_is_continuous_in_the_pose(interpolation):
    """Tiny pose changes give tiny DRR changes: no jumps from a changing number of steps or from
    samples a rounding error outside the clipping box."""
    cam = _camera(0.3)
    vol = _random_volume(9)
    r = DRRRenderer([cam], [vol], device="cpu", step_mm=0.9, interpolation=interpolation)
    base = _rigid([0.2, 0.1, -0.3], [1.0, 2.0, -1.5])
    imgs = []
    for k in range(12):
        T = base.copy()
        T[:3, 3] += k * np.array([0.004, -0.003, 0.005])  # 0.007 mm per step
        imgs.append(r.render_full(T[None], 0))
    jumps = np.abs(np.diff(np.stack(imgs), axis=0)).max(axis=(1, 2))
    # a changed step count would move some pixel by ~1e-2 of the maximum here
    assert jumps.max() < 2e-3 * imgs[0].max(), jumps / imgs[0].max()


def test_bad_arguments_name_the_argument():
    cam = _camera()
    vol = _random_volume(6)
    r = DRRRenderer([cam], [vol], device="cpu")
    with pytest.raises(ValueError, match="poses"):
        r.render(np.eye(3))
    with pytest.raises(ValueError, match="views"):
        r.render(np.eye(4)[None], views=[3])
    with pytest.raises(ValueError, match="roi"):
        r.render(np.eye(4)[None], roi=np.array([0.5, 0, 4, 4]))
    with pytest.raises(ValueError, match="scale"):
        r.render(np.eye(4)[None], scale=0)
    with pytest.raises(ValueError, match="interpolation"):
        DRRRenderer([cam], [vol], device="cpu", interpolation="cubic")
    with pytest.raises(ValueError, match="step_mm"):
        DRRRenderer([cam], [vol], device="cpu", step_mm=-1)
    with pytest.raises(ValueError, match="volumes"):
        DRRRenderer([cam], [], device="cpu")
    nan_pose = np.eye(4)
    nan_pose[0, 3] = np.nan
    with pytest.raises(ValueError, match="poses"):
        r.render(nan_pose[None])


@pytest.mark.parametrize("interpolation", ["trilinear", "texture"])
def test_empty_space_skipping_is_exact(interpolation):
    """A small blob in a large empty box, with a second volume stacked in the atlas."""
    rng = np.random.default_rng(7)
    data = np.zeros((40, 37, 33), np.float32)
    data[18:23, 10:14, 20:26] = rng.random((5, 4, 6)) * 0.05
    data[30, 30, 5] = 0.08  # a lone voxel: thin support at brick borders
    sparse = CTVolume(data, spacing=[0.5, 0.6, 0.7], origin=[-9.0, -10.0, -13.0], units="1/mm")
    cams = Rig((_camera(0.0), _camera(np.deg2rad(100))))
    vols = [_random_volume(8), sparse]
    rng = np.random.default_rng(1)
    poses = np.stack([[_rigid(rng.normal(0, 0.4, 3), rng.normal(0, 2, 3)) for _ in range(2)]
                      for _ in range(3)])
    on = DRRRenderer(cams, vols, device="cpu", interpolation=interpolation, step_mm=0.4)
    off = DRRRenderer(cams, vols, device="cpu", interpolation=interpolation, step_mm=0.4,
                      empty_space_skipping=False)
    a = on.render(poses, roi="full").numpy()
    b = off.render(poses, roi="full").numpy()
    assert b[:, :, 1].max() > 0.01
    # skipped samples are exactly 0; only the float32 grouping of the partial sums may differ
    # (a wrongly skipped sample would change a pixel by ~mu * step, i.e. > 1e-4 relative)
    np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-9)


def test_non_rigid_poses_and_negative_attenuation_are_rejected():
    cam = _camera()
    vol = _random_volume(10)
    r = DRRRenderer([cam], [vol], device="cpu")
    scaled = np.diag([1.1, 1.0, 1.0, 1.0])
    with pytest.raises(ValueError, match="poses: expected rigid"):
        r.render(scaled[None])
    neg = CTVolume(-vol.data, spacing=vol.spacing, origin=vol.origin, units="1/mm", name="neg")
    with pytest.raises(ValueError, match="neg has negative attenuation"):
        DRRRenderer([cam], [neg], device="cpu")


def test_auto_roi_holds_the_whole_drr_even_without_margin():
    """The interpolant reaches half a voxel beyond the outer voxel faces: coarse voxels."""
    cam = _camera(0.2)
    data = np.full((4, 5, 6), 0.02, np.float32)
    vol = CTVolume(data, spacing=[4.0, 4.0, 4.0], origin=[-10.0, -8.0, -6.0], units="1/mm")
    r = DRRRenderer([cam], [vol], device="cpu")
    T = _rigid([0.1, 0.3, 0.0], [1.0, 0.0, 0.0])[None]
    full = r.render(T, roi="full").numpy()[0, 0, 0]
    auto = r.render(T, margin=0)
    _, _, w, h = auto.roi[0, 0, 0]
    assert 0 < w < cam.width and 0 < h < cam.height
    np.testing.assert_allclose(auto.item(0, 0, 0).sum(), full.sum(), rtol=1e-6)
