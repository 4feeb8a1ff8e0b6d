"""MayaCam 1.0 / 2.0 reading and writing (core.geometry.mayacam).

Besides round trips, the files are checked against an independent re-implementation of
Autoscoper's loaders (``libautoscoper/src/Camera.cpp`` ``loadMayaCam1/2`` with
``CoordFrame::from_xyzypr``/``rotate``, transcribed with their storage order), which gives the
camera frame Autoscoper renders with: columns (right, up, back) in the lab, looking along -z.
For a Talus camera that frame must be ``R.T @ diag(1, -1, -1)``, at the source, with the
principal point ``(cu, (height - 1) - cv)`` (rows counted from the bottom).
"""

import math
import os
import re
from pathlib import Path

import numpy as np
import pytest

from core.geometry import Camera, make_K, read_mayacam, rig_from_mayacam, write_mayacam

FLIP_YZ = np.diag([1.0, -1.0, -1.0])


# ---------------------------------------------------------------------------- Autoscoper replica
def _cf_rotate(rot, axis, angle_deg):
    """CoordFrame::rotate on the flat 9-array (column-major rotation storage)."""
    ax = np.asarray(axis, float) / np.linalg.norm(axis)
    c, s = math.cos(math.radians(angle_deg)), math.sin(math.radians(angle_deg))
    x, y, z = ax
    oc = 1 - c
    R = [
        oc * x * x + c, oc * x * y + s * z, oc * x * z - s * y,
        oc * x * y - s * z, oc * y * y + c, oc * y * z + s * x,
        oc * x * z + s * y, oc * y * z - s * x, oc * z * z + c,
    ]  # fmt: skip
    return (np.reshape(rot, (3, 3)) @ np.reshape(R, (3, 3))).ravel()


def _autoscoper_load(path):
    """Return (A cam->lab with columns right/up/back, position, (u0, v0 from bottom), z, size)."""
    lines = Path(path).read_text().splitlines()
    if lines[0] == "image size":
        size = [float(v) for v in lines[1].split(",")[:2]]
        K = np.zeros((3, 3))
        rot = np.zeros((3, 3))
        for i in (4, 5, 6):
            for j, v in enumerate(lines[i].split(",")[:3]):
                K[j][i - 4] = float(v)  # stored transposed, as in the C++
        for i in (9, 10, 11):
            for j, v in enumerate(lines[i].split(",")[:3]):
                rot[j][i - 9] = float(v)
        tr = np.array([float(lines[i]) for i in (14, 15, 16)])
        tr[0], tr[2] = -tr[0], -tr[2]
        rot[:, 0] *= -1
        rot[:, 2] *= -1
        K[2][1] = (size[1] - 1) - K[2][1]
        rot = rot.T.copy()
        tr = np.array([-(tr[0] * rot[0][i] + tr[1] * rot[1][i] + tr[2] * rot[2][i]) for i in range(3)])
        rot[0] *= -1
        rot[1] *= -1
        A = rot.ravel().reshape(3, 3).T  # CoordFrame(&rotation[0][0]) -> column-major
        return A, tr, (K[2][0], K[2][1]), -0.5 * (K[0][0] + K[1][1]), size
    csv = [[float(v) for v in ln.split(",")[:3]] for ln in lines[:5]]
    u0, v0, z = csv[3][0] - 1, csv[3][1] - 1, csv[3][2]
    size = [csv[4][1] or 1024, csv[4][2] or 1024]
    yaw, pitch, roll = csv[1][2], csv[1][1], csv[1][0]
    rot = np.eye(3).ravel()
    rot = _cf_rotate(rot, rot[6:9], yaw)
    rot = _cf_rotate(rot, rot[3:6], pitch)
    rot = _cf_rotate(rot, rot[0:3], roll)
    return rot.reshape(3, 3).T, np.array(csv[0]), (u0, v0), z, size


def _assert_autoscoper_agrees(path, cam: Camera, *, f=None):
    A, pos, (u0, v0), z, size = _autoscoper_load(path)
    np.testing.assert_allclose(A, cam.R.T @ FLIP_YZ, atol=1e-9)
    np.testing.assert_allclose(pos, cam.source, atol=1e-6)
    assert u0 == pytest.approx(cam.cu, abs=1e-9)
    assert v0 == pytest.approx((cam.height - 1) - cam.cv, abs=1e-9)
    assert -z == pytest.approx(f if f is not None else 0.5 * (cam.fx + cam.fy), rel=1e-12)
    assert size == [cam.width, cam.height]


def _random_camera(seed, *, square=False, width=1024, height=768):
    rng = np.random.default_rng(seed)
    z = rng.standard_normal(3)
    z /= np.linalg.norm(z)
    x = np.cross(rng.standard_normal(3), z)
    x /= np.linalg.norm(x)
    R = np.vstack([x, np.cross(z, x), z])
    source = -1400 * z + rng.uniform(-30, 30, 3)
    fx = rng.uniform(5000, 6000)
    fy = fx if square else fx * 1.004
    K = make_K(fx, fy, width / 2 + rng.uniform(-30, 30), height / 2 + rng.uniform(-30, 30))
    return Camera(K, R, -R @ source, width, height, 0.3, "cam")


def _same_camera(a: Camera, b: Camera, tol=1e-9):
    np.testing.assert_allclose(a.K, b.K, rtol=tol)
    np.testing.assert_allclose(a.R, b.R, atol=tol)
    np.testing.assert_allclose(a.t, b.t, rtol=tol, atol=tol * 1e3)
    assert (a.width, a.height) == (b.width, b.height)


# ---------------------------------------------------------------------------- real files
@pytest.fixture
def calibration_files(sample_data) -> list[Path]:
    folder = sample_data / "autoscoper_wrist" / "Calibration"
    if not folder.is_dir():
        pytest.skip(reason=f"Autoscoper sample calibrations not found in {folder}")
    files = sorted(folder.glob("*.txt"))
    assert files, f"no MayaCam files in {folder}"
    return files


@pytest.mark.realdata
def test_every_real_mayacam_file(calibration_files, tmp_path):
    for path in calibration_files:
        cam = read_mayacam(path)
        assert cam.name == path.stem
        # sanity: source 0.5-2 m from the lab origin, plausible X-ray focal lengths
        assert 500 < np.linalg.norm(cam.source) < 2000, path.name
        assert 3000 < cam.fx < 15000 and 3000 < cam.fy < 15000, path.name
        assert abs(cam.fx / cam.fy - 1) < 0.05, path.name
        assert 0 < cam.cu < cam.width and 0 < cam.cv < cam.height, path.name
        _assert_autoscoper_agrees(path, cam)
        out = tmp_path / f"{path.stem}_v2.txt"
        write_mayacam(cam, out)
        back = read_mayacam(out)
        _same_camera(back, cam, tol=1e-12)
        _assert_autoscoper_agrees(out, cam)
        # MayaCam 1.0 keeps one focal length (the mean) and everything else
        out1 = tmp_path / f"{path.stem}_v1.csv"
        write_mayacam(cam, out1, version=1, average_focal=True)
        _assert_autoscoper_agrees(out1, cam)
        back1 = read_mayacam(out1)
        np.testing.assert_allclose(back1.R, cam.R, atol=1e-9)
        np.testing.assert_allclose(back1.source, cam.source, atol=1e-6)
        assert back1.fx == back1.fy == pytest.approx(0.5 * (cam.fx + cam.fy))
        assert (back1.cu, back1.cv) == pytest.approx((cam.cu, cam.cv), abs=1e-9)


@pytest.mark.realdata
def test_real_rigs_look_at_a_common_volume(calibration_files):
    """Principal rays of each pair pass within a few cm of each other, in front of both sources
    (a transposed R or a camera looking along -z would fail this)."""
    pairs = {}
    for path in calibration_files:
        pairs.setdefault(re.sub(r"_cam0\d$", "", path.stem), []).append(path)
    assert len(pairs) == 3
    for paths in pairs.values():
        rig = rig_from_mayacam(sorted(paths), pixel_size=0.2)
        a, b = rig
        M = np.column_stack([a.principal_ray, -b.principal_ray])
        s = np.linalg.lstsq(M, b.source - a.source, rcond=None)[0]
        gap = np.linalg.norm(a.source + s[0] * a.principal_ray - b.source - s[1] * b.principal_ray)
        assert gap < 50 and np.all(s > 500), (paths, gap, s)
        assert np.radians(30) < rig.angle_between_views() < np.radians(150)
        assert a.sid == pytest.approx(0.2 * a.fx)


# ---------------------------------------------------------------------------- synthetic files
def test_v2_round_trip_and_layout(tmp_path):
    cam = _random_camera(0)
    path = tmp_path / "cam.txt"
    write_mayacam(cam, path)
    lines = path.read_text().splitlines()
    assert lines[0] == "image size" and lines[1] == "1024,768"  # width,height
    assert [lines[i] for i in (3, 8, 13)] == ["camera matrix", "rotation", "translation"]
    assert [lines[i] for i in (2, 7, 12)] == ["", "", ""]
    back = read_mayacam(path, pixel_size=0.3, name="x")
    _same_camera(back, cam, tol=0)  # full-precision numbers: bit-identical
    assert back.name == "x" and back.pixel_size == 0.3
    _assert_autoscoper_agrees(path, cam)


def test_v1_round_trip_matches_autoscoper(tmp_path):
    for seed in range(5):
        cam = _random_camera(seed, square=True)
        path = tmp_path / f"cam{seed}.csv"
        write_mayacam(cam, path, version=1)
        assert len(path.read_text().splitlines()) == 5
        _same_camera(read_mayacam(path), cam, tol=1e-10)
        _assert_autoscoper_agrees(path, cam)


def test_v1_documented_example(tmp_path):
    """The MayaCam 1.0 example of Autoscoper's documentation."""
    path = tmp_path / "example.csv"
    path.write_text(
        "-737.5,-514.9,94.3\n89.7,-2.0,-55.2\n3.9,4.1,-632.5\n840.2,839.2,-6325.8\n0.1,1760,1760\n"
    )
    cam = read_mayacam(path)
    np.testing.assert_allclose(cam.source, [-737.5, -514.9, 94.3], atol=1e-9)
    assert cam.fx == cam.fy == 6325.8
    assert (cam.cu, cam.cv) == pytest.approx((839.2, 1760 - 839.2))
    assert (cam.width, cam.height) == (1760, 1760)
    _assert_autoscoper_agrees(path, cam)
    # the source looks towards the lab origin region (principal ray within ~10 deg of it)
    cosang = cam.principal_ray @ (-cam.source / np.linalg.norm(cam.source))
    assert cosang > np.cos(np.radians(10))


def test_v1_zero_size_means_1024(tmp_path):
    path = tmp_path / "old.csv"
    path.write_text("0,0,1000\n0,0,0\n0,0,-1\n512.5,512.5,-5000\n0.1,0,0\n")
    cam = read_mayacam(path)
    assert (cam.width, cam.height) == (1024, 1024)
    # zero angles: a Maya/OpenGL camera looking down the lab's -z, y up (so image rows go -y)
    np.testing.assert_allclose(cam.principal_ray, [0, 0, -1], atol=1e-12)
    np.testing.assert_allclose(cam.R, np.diag([1.0, -1.0, -1.0]), atol=1e-12)
    assert (cam.cu, cam.cv) == (511.5, 1024 - 512.5)


def test_v1_requires_equal_focal_lengths(tmp_path):
    cam = _random_camera(1)
    with pytest.raises(ValueError, match=r"camera: MayaCam 1\.0 stores a single focal length"):
        write_mayacam(cam, tmp_path / "x.csv", version=1)
    assert not (tmp_path / "x.csv").exists()
    write_mayacam(cam, tmp_path / "x.csv", version=1, average_focal=True)
    assert read_mayacam(tmp_path / "x.csv").fx == pytest.approx(0.5 * (cam.fx + cam.fy))


def test_reader_tolerates_crlf_bom_and_spaces(tmp_path):
    cam = _random_camera(2)
    clean = tmp_path / "clean.txt"
    write_mayacam(cam, clean)
    messy = tmp_path / "messy.txt"
    text = "\r\n".join(" " + ln.replace(",", " , ") + "  " for ln in clean.read_text().splitlines())
    messy.write_bytes(b"\xef\xbb\xbf" + text.encode() + b"\r\n\r\n")
    _same_camera(read_mayacam(messy), cam, tol=0)


def test_undistortion_section(tmp_path):
    cam = _random_camera(3)
    path = tmp_path / "d.txt"
    write_mayacam(cam, path)
    base = path.read_text()
    path.write_text(base + "\nundistortion\n0,0,0,0,0,0,0,0\n")
    _same_camera(read_mayacam(path), cam, tol=0)
    path.write_text(base + "\nundistortion\n-0.1,0,0,0,0,0,0,0\n")
    with pytest.raises(ValueError, match=r"d\.txt: section 'undistortion' \(line 19\): non-zero"):
        read_mayacam(path)
    _same_camera(read_mayacam(path, ignore_distortion=True), cam, tol=0)


V2 = """image size
1024,768

camera matrix
5000,0,512
0,5000,384
0,0,1

rotation
1,0,0
0,1,0
0,0,1

translation
0
0
1400
"""


@pytest.mark.parametrize(
    ("text", "match"),
    [
        (V2.replace("translation\n0\n0\n1400\n", ""), r"missing section\(s\) \['translation'\]"),
        (V2.replace("0,5000,384", "0,5000,abc"), r"line 6 \(section 'camera matrix'\): expected 3"),
        (V2.replace("0,1,0\n", "0,1.5,0\n"), r"section 'rotation': R: expected an orthonormal"),
        (V2.replace("0,0,1\n\ntrans", "0,0,-1\n\ntrans"), r"section 'rotation': R: expected a proper"),
        (V2.replace("1024,768", "1024"), r"line 2 \(section 'image size'\): expected 2"),
        (V2.replace("1024,768", "1024.5,768"), r"line 2 .*expected positive integer width,height"),
        (V2.replace("rotation", "orientation"), r"line 9: expected a section header"),
        (V2 + "\nrotation\n1,0,0\n0,1,0\n0,0,1\n", r"line 19: section 'rotation' appears twice"),
        (V2.split("translation")[0] + "translation\n0\n0\n", r"section 'translation' \(line 14\)"),
        (V2.replace("0,5000,384", "1,5000,384"), r"section 'camera matrix': K: expected an upper"),
        (V2.replace("5000,0,512", "-5000,0,512"), r"section 'camera matrix': K: expected positive"),
        (V2.replace("1400", "nan"), r"line 17 \(section 'translation'\): expected 1"),
        ("", r"empty file"),
        ("1,2,3\n4,5,6\n7,8,9\n1,2,-3\n", r"MayaCam 1.0: expected 5 non-empty lines"),
        ("1,2,3\n4,5,6\n7,8,9\n1,2,3\n0.1,10,10\n", r"line 4 \(u0,v0,z\): expected z = -\(focal"),
        ("1,2,3\n4,5\n7,8,9\n1,2,-3\n0.1,10,10\n", r"line 2 \(rotation angles \(deg\)\)"),
        ("1,2,3\n4,5,6\n7,8,9\n1,2,-3\n0.1,10.5,10\n", r"line 5 .*positive integer width,height"),
    ],
)
def test_malformed_files_name_file_and_line(tmp_path, text, match):
    path = tmp_path / "bad_cam.txt"
    path.write_text(text)
    with pytest.raises(ValueError, match=re.escape(str(path)) + ".*" + match):
        read_mayacam(path)


def test_binary_file_is_rejected(tmp_path):
    path = tmp_path / "image.tif"
    path.write_bytes(b"II*\x00\xff\xfe\x80")
    with pytest.raises(ValueError, match=re.escape(str(path)) + ": expected a text MayaCam file"):
        read_mayacam(path)


def test_write_is_atomic(tmp_path, monkeypatch):
    cam = _random_camera(4)
    path = tmp_path / "cam.txt"
    path.write_text("previous content\n")
    write_mayacam(cam, path)
    _same_camera(read_mayacam(path), cam, tol=0)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cam.txt"]  # no temporary left
    before = path.read_bytes()

    def failing_replace(src, dst):
        raise OSError("disk full")

    monkeypatch.setattr(os, "replace", failing_replace)
    with pytest.raises(OSError, match="disk full"):
        write_mayacam(_random_camera(5), path)
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cam.txt"]


def test_write_and_rig_reject_bad_arguments(tmp_path):
    cam = _random_camera(6)
    with pytest.raises(ValueError, match="version: expected 1 or 2"):
        write_mayacam(cam, tmp_path / "x.txt", version=3)
    with pytest.raises(ValueError, match="camera: expected a Camera"):
        write_mayacam("cam", tmp_path / "x.txt")
    assert not any(tmp_path.iterdir())
    paths = [tmp_path / "a.txt", tmp_path / "b.txt"]
    for p in paths:
        write_mayacam(cam, p)
    rig = rig_from_mayacam(paths, pixel_size=[0.2, 0.3])
    assert [c.name for c in rig] == ["a", "b"] and [c.pixel_size for c in rig] == [0.2, 0.3]
    assert rig_from_mayacam(paths).cameras[0].pixel_size is None
    with pytest.raises(ValueError, match="paths: expected a non-empty sequence"):
        rig_from_mayacam(str(paths[0]))
    with pytest.raises(ValueError, match="paths: expected a non-empty sequence"):
        rig_from_mayacam([])
    with pytest.raises(ValueError, match="pixel_size: expected one value or 2"):
        rig_from_mayacam(paths, pixel_size=[0.2])
    with pytest.raises(ValueError, match="pixel_size: expected a positive"):
        read_mayacam(paths[0], pixel_size=0)
