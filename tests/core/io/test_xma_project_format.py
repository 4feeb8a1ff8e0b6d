"""XMALab .xma projects: the writer round-trips through the reader, a project laid out by hand as
XMALab's ProjectFileIO.cpp writes it (Windows separators, CRLF, ", " separators, status files)
reads, the undistortion grid's local weighted mean is XMALab's, and damaged projects raise
FileError naming the file."""

from __future__ import annotations

import itertools
import zipfile

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from core.errors import FileError
from core.geometry.camera import Camera
from core.io.xma_project import (
    XMAGrid,
    XMAMarkerData,
    XMATrialData,
    read_xma_project,
    write_xma_project,
)

W, H = 64, 48


def cameras() -> list[Camera]:
    K = [np.array([[300.0, 0, 31.5], [0, 302.0, 24.0], [0, 0, 1]]),
         np.array([[310.0, 0, 33.0], [0, 309.0, 22.5], [0, 0, 1]])]
    R = [Rotation.from_euler("xyz", a, degrees=True).as_matrix() for a in ([5, 30, -2], [-4, -35, 3])]
    t = [np.array([10.0, -20.0, 900.0]), np.array([-15.0, 5.0, 950.0])]
    return [Camera(K=K[i], R=R[i], t=t[i], width=W, height=H, name=f"cam{i + 1}") for i in range(2)]


def radial(uv, k=2e-5, c=(31.5, 23.5)):
    """A pincushion distortion of ideal pixels (ideal → distorted)."""
    d = np.asarray(uv, float) - c
    r2 = (d**2).sum(-1, keepdims=True)
    return c + d * (1 + k * r2)


def grid(step=4.0) -> XMAGrid:
    u, v = np.meshgrid(np.arange(2.0, W - 1, step), np.arange(2.0, H - 1, step))
    ref = np.column_stack([u.ravel(), v.ravel()])
    inl = np.ones(len(ref), bool)
    inl[::17] = False
    return XMAGrid(radial(ref), ref, inl)


def markers(n=4):
    rng = np.random.default_rng(3)
    X = rng.uniform(-20, 20, (n, 3))
    cams = cameras()
    P = np.stack([np.asarray(c.project(X)) for c in cams], axis=1)
    P[1, 0] = np.nan  # marker unset in camera 1 at frame 1
    X3 = X.copy()
    X3[1] = np.nan
    return [XMAMarkerData("bead 1", P, X3), XMAMarkerData("bead2", P + 1.0)]


def project(path, views=None, **kw):
    views = views or [[f"/data/hop/cam{i}/hop_cam{i}.{k:04d}.tif" for k in range(1, 5)] for i in (1, 2)]
    tr = XMATrialData("hop 1", views, markers(), {"tibia": [0, 1]}, recording_speed=250.0,
                      cutoff_frequency=25.0)
    g = grid()
    return write_xma_project(path, cameras(), [tr], grids=[g, None],
                             distortion_coeffs=[None, np.array([1e-3, -2e-4, 0, 0, 0, 0, 0, 0])], **kw)


def test_round_trip(tmp_path):
    p = project(tmp_path / "rt.xma")
    prj = read_xma_project(p)
    assert prj.version == "0.3" and prj.calibration_type == 2
    assert [c.name for c in prj.cameras] == ["cam1", "cam2"]
    (t,) = prj.trials
    assert (t.name, t.n_images, t.recording_speed, t.cutoff_frequency) == ("hop 1", 4, 250.0, 25.0)
    assert t.rigid_bodies == ("tibia",) and [m.description for m in t.markers] == ["bead 1", "bead2"]
    rig = prj.rig("hop 1")
    for a, b in zip(rig, cameras(), strict=True):
        np.testing.assert_array_equal(a.K, b.K)
        np.testing.assert_array_equal(a.R, b.R)
        np.testing.assert_array_equal(a.t, b.t)
        assert (a.width, a.height) == (W, H)
    g, g2 = grid(), prj.grid("cam1")
    np.testing.assert_array_equal(g2.distorted, g.distorted)
    np.testing.assert_array_equal(g2.references, g.references)
    np.testing.assert_array_equal(g2.inlier, g.inlier)
    assert prj.grid("cam2") is None
    assert prj.cameras[0].distortion_coeffs is None
    np.testing.assert_array_equal(prj.cameras[1].distortion_coeffs, [1e-3, -2e-4, 0, 0, 0, 0, 0, 0])
    ms = markers()
    for i, m in enumerate(ms):
        np.testing.assert_array_equal(prj.marker_points("hop 1", i), m.points2d)  # NaN where unset
        np.testing.assert_array_equal(prj.marker_points3d("hop 1", i), m.points3d)
    assert prj.marker_status("hop 1", 0)[1].tolist() == [0, 50]
    assert prj.view_files("hop 1")[1][2] == "/data/hop/cam2/hop_cam2.0003.tif"


def _xmalab_text(path):
    """The members XMALab itself writes for the same project: Windows separators in the XML, CRLF
    line ends (a project saved on Windows), ``-2,-2`` placeholders without a status file."""
    with zipfile.ZipFile(path) as zf:
        members = {n: zf.read(n) for n in zf.namelist()}
    xml = members["project.xml"].decode()
    for a, b in (("cam1/data/", "cam1\\data\\"), ("hop 1/data/", "hop 1\\data\\"),
                 (' FilenameStatus2D="hop 1/data/Marker001status2d.csv"', "")):
        xml = xml.replace(a, b)
    members["project.xml"] = xml.replace("\n", "\r\n").encode()
    for k in list(members):
        if k.endswith(".csv") or k.endswith(".txt"):
            members[k] = members[k].replace(b"\n", b"\r\n")
    del members["hop 1/data/Marker001status2d.csv"]
    return members


def test_a_project_as_xmalab_saves_it_on_windows(tmp_path):
    p = project(tmp_path / "a.xma")
    members = _xmalab_text(p)
    q = tmp_path / "win.xma"
    with zipfile.ZipFile(q, "w") as zf:
        for k, v in members.items():
            zf.writestr(k, v)
    prj = read_xma_project(q)
    np.testing.assert_array_equal(prj.grid("cam1").references, grid().references)
    P = markers()[1].points2d
    np.testing.assert_array_equal(prj.marker_points("hop 1", 1), P)
    assert prj.marker_status("hop 1", 1) is None
    assert prj.view_files("hop 1")[0][0] == "/data/hop/cam1/hop_cam1.0001.tif"


def _xmalab_lwm(ctrl, target, n=12):
    """XMALab's LocalUndistortion::computeLWM (LocalUndistortion.cpp 247-328), written out: per
    control point a quadratic in absolute coordinates through its n nearest points (itself
    included), radius the distance to the n-th."""
    A = np.empty((len(ctrl), 6, 2))
    radii = np.empty(len(ctrl))
    for i, c in enumerate(ctrl):
        d = np.linalg.norm(ctrl - c, axis=1)
        idx = np.argsort(d, kind="stable")[:n]
        radii[i] = d[idx[-1]]
        x, y = ctrl[idx, 0], ctrl[idx, 1]
        X = np.stack([np.ones(n), x, y, x * y, x * x, y * y], 1)
        A[i] = np.linalg.pinv(X) @ target[idx]
    return A, radii


def _xmalab_transform(pt, ctrl, A, radii):
    """UndistortionObject::transformLWM (UndistortionObject.cpp 339-400)."""
    x, y = pt
    num, den = np.zeros(2), 0.0
    for c, a, r in zip(ctrl, A, radii, strict=True):
        R = np.hypot(x - c[0], y - c[1]) / r
        if R < 1:
            w = 1 - 3 * R**2 + 2 * R**3
            num += w * (np.array([1, x, y, x * y, x * x, y * y]) @ a)
            den += w
    return num / den if den else np.array(pt, float)


def test_the_grid_model_is_xmalabs_local_weighted_mean():
    """Equal to XMALab's to 1e-8 px on reference points without ties in their neighbour distances;
    on a perfect lattice the 12th neighbour is a tie that the two sorts may break differently
    (1.2e-3 px at most on this 4-px grid)."""
    from core.study.import_xma import xma_distortion_model

    g0 = grid()
    ref = g0.references + np.random.default_rng(2).uniform(-0.3, 0.3, g0.references.shape)
    g = XMAGrid(radial(ref), ref, g0.inlier)
    keep = g.inlier
    model = xma_distortion_model(g)
    assert model.label == "lwm(12)"
    A, radii = _xmalab_lwm(g.references[keep], g.distorted[keep])
    rng = np.random.default_rng(0)
    pts = rng.uniform([4, 4], [W - 5, H - 5], (40, 2))
    ref = np.array([_xmalab_transform(p, g.references[keep], A, radii) for p in pts])
    np.testing.assert_allclose(model.forward(pts), ref, atol=1e-8)
    # the correction (distorted → ideal) inverts it, as XMALab's refined undistortPoint does
    np.testing.assert_allclose(model.inverse(ref), pts, atol=1e-6)


def test_lens_coefficients_compose_with_the_grid():
    from core.study.import_xma import _opencv_distort, xma_distortion_model

    K = cameras()[1].K
    k = np.array([1e-3, -2e-4, 1e-4, -1e-4, 0, 0, 0, 0])
    g = grid()
    m = xma_distortion_model(g, coeffs=k, K=K, size=(W, H))
    grid_only = xma_distortion_model(g)
    pts = np.random.default_rng(1).uniform([6, 6], [W - 7, H - 7], (30, 2))
    want = grid_only.forward(_opencv_distort(pts, K, k))
    np.testing.assert_allclose(m.forward(pts), want, atol=1e-3)
    assert xma_distortion_model(None, coeffs=np.zeros(8), K=K, size=(W, H)) is None


@pytest.mark.parametrize("drop", ["project.xml", "cam1/data/UndistortionGrid_GridPointsReferences.csv",
                                  "cam2/data/external_TranslationVector.csv"])
def test_missing_members_name_the_file(tmp_path, drop):
    p = project(tmp_path / "a.xma")
    with zipfile.ZipFile(p) as zf:
        members = {n: zf.read(n) for n in zf.namelist() if n != drop}
    q = tmp_path / "bad.xma"
    with zipfile.ZipFile(q, "w") as zf:
        for k, v in members.items():
            zf.writestr(k, v)
    with pytest.raises(FileError, match=r"bad\.xma"):
        read_xma_project(q)


def test_the_writer_checks_its_arguments(tmp_path):
    with pytest.raises(ValueError, match="grids"):
        write_xma_project(tmp_path / "x.xma", cameras(), grids=[None])
    bad = XMATrialData("t", [["a.avi"], ["b.avi"]], [XMAMarkerData("m", np.zeros((3, 1, 2)))])
    with pytest.raises(ValueError, match="points2d"):
        write_xma_project(tmp_path / "x.xma", cameras(), [bad])
    assert not (tmp_path / "x.xma").exists()


# ---------------------------------------------------------------------------- fuzz
_n = itertools.count()
ALPHABET = st.sampled_from([*"0123456789.,-+ e\n\r<>/=\"\\", "NaN", "inf", "-2", "Camera", "Trial", "Marker",
                            "Filename", "Width", "ID"])
FUZZ = settings(max_examples=60, deadline=None, database=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])


@st.composite
def mutated(draw, text: bytes) -> bytes:
    s = list(text.decode("latin-1"))
    for _ in range(draw(st.integers(1, 5))):
        op = draw(st.sampled_from(["delete", "insert", "replace", "truncate"]))
        i = draw(st.integers(0, 1 << 20)) % (len(s) + 1)
        if op == "delete" and s:
            del s[i:min(len(s), i + draw(st.integers(1, 20)))]
        elif op == "insert":
            s[i:i] = list(draw(ALPHABET))
        elif op == "replace" and i < len(s):
            s[i] = draw(ALPHABET)
        elif op == "truncate":
            del s[i:]
    return "".join(s).encode("latin-1")


@pytest.fixture(scope="module")
def good_members(tmp_path_factory):
    p = project(tmp_path_factory.mktemp("xma") / "good.xma")
    with zipfile.ZipFile(p) as zf:
        return {n: zf.read(n) for n in zf.namelist() if not n.endswith(".tif")}


@FUZZ
@given(data=st.data())
def test_damaged_projects_raise_file_error_naming_the_file(tmp_path_factory, good_members, data):
    members = dict(good_members)
    name = data.draw(st.sampled_from(sorted(members)))
    members[name] = data.draw(mutated(members[name]))
    p = tmp_path_factory.mktemp("fz") / f"f{next(_n)}.xma"
    with zipfile.ZipFile(p, "w") as zf:
        for k, v in members.items():
            zf.writestr(k, v)
    try:
        prj = read_xma_project(p)
        for c in prj.cameras:
            prj.grid(c.name)
        for t in prj.trials:
            prj.rig(t.name, sizes=[(W, H)] * len(prj.cameras))
            prj.view_files(t.name)
            for m in t.markers:
                prj.marker_points(t.name, m.id)
                prj.marker_status(t.name, m.id)
                prj.marker_points3d(t.name, m.id)
    except FileError as exc:
        assert str(p) in str(exc), str(exc)
    except ValueError as exc:  # a lookup the damaged file no longer has, or a camera it no longer defines
        assert str(p) in str(exc) or any(w in str(exc) for w in ("trial", "marker", "camera")), str(exc)
