"""Calibration objects: built-ins, definition files and micro-CT bead extraction."""

import json

import numpy as np
import pytest

from core.calibration.microct import extract_beads, target_from_volume
from core.calibration.objects import (
    CalibrationTarget,
    builtin_target,
    cube_target,
    read_target,
    spiral_target,
    write_target,
)
from core.render.volume import CTVolume
from core.synthetic.calib_objects import calibration_cube, helical_spiral


def test_builtins_follow_the_thesis_and_reuse_the_synthetic_geometry():
    cube = cube_target()
    assert len(cube) == 15 and cube.kind == "cube"
    sizes, cls = cube.size_classes
    np.testing.assert_allclose(sizes, [1.78, 3.17, 4.76])
    assert np.bincount(cls).tolist() == [5, 5, 5]
    np.testing.assert_array_equal(cube.centers, calibration_cube().centers)
    for n in (23, 33):
        sp = builtin_target(f"spiral{n}")
        assert len(sp) == n and sp.kind == "spiral"
        np.testing.assert_array_equal(sp.diameters[:4], [3.0, 5.0, 3.0, 5.0])
        np.testing.assert_array_equal(sp.centers, helical_spiral(n).centers)
    custom = spiral_target(12, radius_mm=20, turns=2, diameters=[3, 5, 5] * 4)
    assert len(custom) == 12 and custom.size_classes[0].tolist() == [3.0, 5.0]
    with pytest.raises(ValueError, match="name"):
        builtin_target("sphere")


def test_target_validation_names_the_argument():
    with pytest.raises(ValueError, match="bead_ids"):
        CalibrationTarget("x", ["a", "a"], np.zeros((2, 3)), [1, 1])
    with pytest.raises(ValueError, match="diameters"):
        CalibrationTarget("x", ["a", "b"], np.zeros((2, 3)), [1, -1])
    with pytest.raises(ValueError, match="kind"):
        CalibrationTarget("x", ["a"], np.zeros((1, 3)), [1], kind="torus")
    with pytest.raises(ValueError, match="bead_id"):
        cube_target().index("nope")


@pytest.mark.parametrize("suffix", [".csv", ".json"])
def test_definition_file_round_trip(tmp_path, suffix):
    tg = spiral_target(23)
    tg = CalibrationTarget(tg.name, tg.bead_ids, tg.centers, tg.diameters, kind="spiral",
                           frame=tg.frame, metadata={"serial": "S-07", "scan_mm": 0.145})
    p = tmp_path / f"obj{suffix}"
    write_target(tg, p)
    back = read_target(p)
    assert back.bead_ids == tg.bead_ids and back.kind == "spiral" and back.frame == tg.frame
    assert back.metadata == {"serial": "S-07", "scan_mm": 0.145}
    np.testing.assert_array_equal(back.centers, tg.centers)
    np.testing.assert_array_equal(back.diameters, tg.diameters)


def test_definition_file_errors_name_file_and_line(tmp_path):
    p = tmp_path / "bad.csv"
    p.write_text("# name: x\nid,x,y,diameter\n")
    with pytest.raises(ValueError, match=r"bad.csv.*line 2.*\['z'\]"):
        read_target(p)
    p.write_text("id,x,y,z,diameter\nA,1,2,three,4\n")
    with pytest.raises(ValueError, match=r"line 2.*numbers"):
        read_target(p)
    p.write_text("id,x,y,z,diameter\nA,1,2,3,4\nA,1,2,3,4\n")
    with pytest.raises(ValueError, match="unique"):
        read_target(p)
    j = tmp_path / "bad.json"
    j.write_text(json.dumps({**cube_target().to_dict(), "version": 9}))
    with pytest.raises(ValueError, match="version 9"):
        read_target(j)
    with pytest.raises(ValueError, match="no such"):
        read_target(tmp_path / "missing.csv")


def _scan(centers, diameters, spacing=0.5, bead=3000.0, body=100.0, seed=0):
    """A micro-CT-like volume: partial-volume spheres (5³ sub-voxel samples) in a uniform body."""
    lo = centers.min(axis=0) - 6
    shape = np.ceil((centers.max(axis=0) + 6 - lo) / spacing).astype(int)  # (nx, ny, nz)
    data = np.full(shape[::-1], body, np.float32)
    sub = (np.arange(5) - 2) / 5 * spacing
    so = np.stack(np.meshgrid(sub, sub, sub, indexing="ij"), -1).reshape(-1, 3)
    for c, d in zip(centers, diameters, strict=True):
        r = d / 2
        i0 = np.floor((c - r - lo) / spacing).astype(int) - 1
        i1 = np.ceil((c + r - lo) / spacing).astype(int) + 2
        ii, jj, kk = np.meshgrid(*[np.arange(a, b) for a, b in zip(i0, i1, strict=True)], indexing="ij")
        vox = np.stack([ii, jj, kk], -1).reshape(-1, 3)
        p = lo + vox * spacing
        occ = (np.linalg.norm(p[:, None] + so[None] - c, axis=2) <= r).mean(axis=1)
        data[vox[:, 2], vox[:, 1], vox[:, 0]] += occ * (bead - body)
    data += np.random.default_rng(seed).normal(0, 5.0, data.shape).astype(np.float32)
    return CTVolume(data, spacing=[spacing] * 3, origin=lo, units="1")


def test_micro_ct_beads_recover_the_spiral_in_its_helix_frame():
    tg = spiral_target(23)
    g = np.random.default_rng(3)
    from scipy.spatial.transform import Rotation

    R = Rotation.random(random_state=g).as_matrix()
    lab = tg.centers @ R.T + [12.0, -7.0, 30.0]
    vol = _scan(lab, tg.diameters)
    beads = extract_beads(vol)
    assert len(beads.centers) == 23
    d = np.linalg.norm(beads.centers[:, None] - lab[None], axis=2)
    assert d.min(axis=1).max() < 0.03  # intensity-weighted centroids: sub-voxel (0.5 mm voxels)
    np.testing.assert_allclose(np.sort(beads.diameters), np.sort(tg.diameters), atol=0.08)
    got = target_from_volume(vol, kind="spiral", name="scan", nominal_diameters=[3.0, 5.0])
    rev = target_from_volume(vol, kind="spiral", name="scan", nominal_diameters=[3.0, 5.0], reverse=True)
    # the helix frame of the scan is the model's frame; which end is "first" is a convention
    a, b = (got, rev) if np.linalg.norm(got.centers[0] - tg.centers[0]) < 1 else (rev, got)
    np.testing.assert_allclose(a.centers, tg.centers, atol=0.05)
    # run from the other end: the same helix, first bead at the other end, z flipped
    np.testing.assert_allclose(np.linalg.norm(b.centers, axis=1), np.linalg.norm(tg.centers[::-1], axis=1),
                               atol=0.05)
    np.testing.assert_allclose(b.centers[:, 2], -tg.centers[::-1, 2], atol=0.05)
    np.testing.assert_array_equal(got.diameters, tg.diameters)
    assert got.metadata["source"] == "micro-CT"
    assert len(got.metadata["measured_diameters_mm"]) == 23


def test_extract_beads_rejects_bad_input():
    with pytest.raises(ValueError, match="volume"):
        extract_beads(np.zeros((4, 4, 4)))
    vol = CTVolume(np.zeros((8, 8, 8), np.float32))
    assert len(extract_beads(vol, threshold=1.0).centers) == 0
    with pytest.raises(ValueError, match="threshold"):
        extract_beads(vol, threshold=-1.0)
