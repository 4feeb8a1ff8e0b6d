"""Autoscoper's volume frame (core.io.autoscoper_pose) against a transcription of its source, and
on the real wrist sample: radius and ulna poses read from a .tra overlay the radiographs."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from core.io.autoscoper_pose import (
    T_autoscoper_from_ct,
    T_autoscoper_from_index,
    autoscoper_volume_geometry,
    lab_from_bone_from_tra,
    tra_from_lab_from_bone,
)
from core.render.volume import CTVolume


def _autoscoper_texel_centres(data_kji: np.ndarray, voxel, flip):
    """Volume-frame position of every non-zero voxel, transcribed from Autoscoper's source:
    flipVolume (VolumeDescription.cpp 66-68), cropVolume, invScale/invTrans (246-252), the
    ray caster's box and its texture read at (t.x, 1 - t.y, -t.z) (RayCaster.cl 36-37, 64)."""
    D, H, W = data_kji.shape
    fl = data_kji
    if flip[0]:
        fl = fl[:, :, ::-1]
    if flip[1]:
        fl = fl[:, ::-1, :]
    if flip[2]:
        fl = fl[::-1, :, :]
    k, i, j = np.nonzero(fl)  # slice, row, column of the flipped stack
    mn = [j.min(), i.min(), k.min()]
    mx = [j.max(), i.max(), k.max()]
    dim = [mx[a] - mn[a] + 1 for a in range(3)]
    inv_scale = [1.0 / (voxel[a] * dim[a]) for a in range(3)]
    inv_trans = [-mn[0] / dim[0], -((H - mx[1] - 1) / dim[1]), mn[2] / dim[2]]
    # texel (c, r, s) of the cropped texture sits at normalised (c + .5) / dim ...
    tex = np.stack([(j - mn[0] + 0.5) / dim[0], (i - mn[1] + 0.5) / dim[1], (k - mn[2] + 0.5) / dim[2]], 1)
    t = np.stack([tex[:, 0], 1.0 - tex[:, 1], -tex[:, 2]], 1)  # ... read at (t.x, 1 - t.y, -t.z)
    p = (t - np.array(inv_trans)) / np.array(inv_scale)
    # raw (unflipped) indices of the same voxels
    ii = W - 1 - j if flip[0] else j
    jj = H - 1 - i if flip[1] else i
    kk = D - 1 - k if flip[2] else k
    return np.stack([ii, jj, kk], 1), p


@pytest.mark.parametrize("flip", list(itertools.product((0, 1), repeat=3)))
def test_volume_frame_matches_autoscoper_source(flip):
    rng = np.random.default_rng(sum(f << n for n, f in enumerate(flip)))
    data = np.zeros((9, 7, 11), np.uint16)  # D, H, W; the bone occupies an off-centre sub-box
    data[2:7, 1:5, 3:10] = rng.integers(1, 1000, (5, 4, 7))
    data[data < 300] = 0
    voxel = (0.4, 0.55, 0.7)
    idx, p = _autoscoper_texel_centres(data, voxel, flip)
    T = T_autoscoper_from_index((11, 7, 9), voxel, flip)
    q = idx @ T[:3, :3].T + T[:3, 3]
    np.testing.assert_allclose(q, p, atol=1e-9)
    # a CTVolume in Autoscoper's geometry has that frame as its physical frame
    origin, direction = autoscoper_volume_geometry((11, 7, 9), voxel, flip)
    vol = CTVolume(data, voxel, origin, direction)
    np.testing.assert_allclose(vol.index_to_physical(idx.astype(float)), p, atol=1e-9)
    np.testing.assert_allclose(T_autoscoper_from_ct(vol, flip), np.eye(4), atol=1e-12)
    assert np.sign(np.linalg.det(direction)) == (-1) ** sum(flip)


def test_pose_round_trip_and_mirror_refused():
    from scipy.spatial.transform import Rotation

    vol = CTVolume(np.ones((5, 6, 7), np.int16), (0.3, 0.4, 0.5), origin=(1.0, -2.0, 3.0))
    rng = np.random.default_rng(0)
    T = np.tile(np.eye(4), (4, 1, 1))
    T[:, :3, :3] = Rotation.random(4, random_state=rng).as_matrix()
    T[:, :3, 3] = rng.normal(0, 50, (4, 3))
    tra = tra_from_lab_from_bone(T, vol)
    np.testing.assert_allclose(lab_from_bone_from_tra(tra, vol), T, atol=1e-12)
    # the same world point: bone point x in Talus <-> its Autoscoper volume-frame coordinates
    x = np.array([0.7, 1.1, 2.3, 1.0])
    xa = T_autoscoper_from_ct(vol) @ x
    np.testing.assert_allclose(tra[0] @ xa, T[0] @ x, atol=1e-9)
    # NaN (untracked) stays NaN
    assert np.isnan(lab_from_bone_from_tra(np.full((4, 4), np.nan), vol)).all()
    with pytest.raises(ValueError, match="autoscoper_volume_geometry"):
        lab_from_bone_from_tra(T[0], vol, flip=(1, 0, 0))
    # ... and reading the stack in Autoscoper's mirrored geometry makes the .tra pose the pose
    o, d = autoscoper_volume_geometry(vol.shape_ijk, vol.spacing, (1, 0, 0))
    mirrored = CTVolume(vol.data, vol.spacing, o, d)
    np.testing.assert_allclose(lab_from_bone_from_tra(T[0], mirrored, (1, 0, 0)), T[0], atol=1e-12)


def test_wrist_tra_poses_overlay_the_radiographs(wrist, tmp_path):
    """Radius and ulna at frame 0099 written as Autoscoper writes a .tra (volume frame, row order,
    commas), read back and converted: the DRR silhouettes sit on the radiographs' edges, better
    than at every 3 mm / 5° perturbation, whether the stacks are read in Talus's frame (converted
    pose) or in Autoscoper's (the file's matrices as they are); reading the file's matrices as
    Talus poses without the conversion puts the bones off the images' edges."""
    from core.io.autoscoper_tra import read_tra, write_tra
    from core.studies.io import autoscoper_wrist as aw

    vols = [wrist.volumes[b] for b in aw.BONES]
    talus = aw.wrist_tra_poses()
    tra = np.stack([tra_from_lab_from_bone(talus[b], vols[b]) for b in range(2)])
    path = tmp_path / "wrist.tra"
    write_tra(path, tra[None])
    assert path.read_text().count(",") == 31  # one line, 2 x 16 values
    back = read_tra(path, n_volumes=2)[0]
    lab = np.stack([lab_from_bone_from_tra(back[b], vols[b]) for b in range(2)])
    np.testing.assert_allclose(lab, talus, atol=1e-9)

    def at_pose(volumes, poses):  # the "at_pose" of aw.scores, without its 24 perturbed renders
        r = aw.render_pair(wrist, volumes, poses)
        n = len(wrist.rig)
        return [sum(aw.edge_agreement(r[b, v][0], r[b, v][1]) for v in range(n)) / n for b in range(2)]

    s_talus = aw.scores(wrist, vols, lab)
    s_as = at_pose(aw.autoscoper_frame_volumes(wrist), back)
    naive = at_pose(vols, back)
    for b, name in enumerate(aw.BONES):
        at, pert = s_talus[name]["at_pose"], s_talus[name]["perturbed"]
        assert at > max(pert), (name, at, pert)
        assert at > 1.2 * np.mean(pert), (name, at, pert)
        assert s_as[b] == pytest.approx(at, rel=1e-3)
        assert naive[b] < 0.8 * at, (name, naive[b], at)
