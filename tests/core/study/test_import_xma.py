"""An XMALab project opened as a Talus study: cameras, the undistortion as the calibration's
correction pipeline, trials referencing their images, markers as a report; a moved project found
through search folders; bad projects refused naming the file, nothing left behind."""

from __future__ import annotations

import itertools
import zipfile

import numpy as np
import pytest
import tifffile
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from core.errors import FileError
from core.io.xma_project import XMAMarkerData, XMATrialData, write_xma_project
from core.study import Study, StudyError
from core.study.calibrations import trial_correction
from core.study.import_xma import import_xma
from tests.core.io.test_xma_project_format import H, W, cameras, grid, markers, radial


def frames(folder, cam, n=4):
    d = folder / f"cam{cam}"
    d.mkdir(parents=True)
    rng = np.random.default_rng(cam)
    paths = []
    for k in range(1, n + 1):
        p = d / f"hop_cam{cam}.{k:04d}.tif"
        tifffile.imwrite(p, rng.integers(0, 4000, (H, W), dtype=np.uint16))
        paths.append(str(p))
    return paths


def make(tmp_path, *, views=None, flipped=False, name="lab.xma"):
    views = views or [frames(tmp_path / "raw", c) for c in (1, 2)]
    tr = XMATrialData("hop 1", views, markers(), {"tibia": [0, 1]}, recording_speed=250.0,
                      cutoff_frequency=25.0)
    p = write_xma_project(tmp_path / name, cameras(), [tr], grids=[grid(), None])
    if flipped:
        with zipfile.ZipFile(p) as zf:
            m = {n: zf.read(n) for n in zf.namelist()}
        m["project.xml"] = m["project.xml"].replace(b'isFlipped="0"', b'isFlipped="1"', 1)
        with zipfile.ZipFile(p, "w") as zf:
            for k, v in m.items():
                zf.writestr(k, v)
    return p


def test_project_opens_as_a_study(tmp_path):
    p = make(tmp_path)
    with import_xma(p, tmp_path / "study") as st:
        assert st.trials == ("hop_1",) and st.calibrations == ("xmalab.v1",) and st.bones == ()
        tr = st.trial("hop_1")
        assert tr.n_frames == 4
        rig = tr.rig()
        for a, b in zip(rig, cameras(), strict=True):
            np.testing.assert_allclose(a.K, b.K, atol=1e-12)
            np.testing.assert_allclose(a.R, b.R, atol=1e-12)
            np.testing.assert_allclose(a.t, b.t, atol=1e-9)
        fix = trial_correction(st, "hop_1")
        assert len(fix) == 2 and len(fix[1].steps) == 0
        (und,) = fix[0].steps
        g = grid()
        keep = g.inlier
        np.testing.assert_allclose(und.model.forward(g.references[keep]), g.distorted[keep], atol=5e-3)
        np.testing.assert_allclose(und.model.inverse(radial([[20.0, 30.0]])), [[20.0, 30.0]], atol=1e-3)
        rep = st.read_report("markers", "hop_1")
        assert rep["cameras"] == ["cam1", "cam2"] and rep["frame_base"] == 0
        assert rep["rigid_bodies"] == ["tibia"]
        P = np.array(rep["markers"][0]["points2d"], dtype=float)
        np.testing.assert_array_equal(P, markers()[0].points2d)
        imp = st.settings["imported_from"]
        assert imp["format"] == "xmalab-xma" and imp["trials"]["hop_1"]["recording_speed_hz"] == 250.0
        assert imp["cameras"]["cam1"]["grid_inliers"] == int(grid().inlier.sum())
        from core.study.exports import recording_rate

        assert recording_rate(st, "hop_1") == 250.0 and recording_rate(st, "other") == 100.0
    with Study.open(tmp_path / "study") as st:  # reopens read-only with every file there
        assert st.trial("hop_1").n_frames == 4


def test_a_moved_project_finds_its_images_in_search_folders(tmp_path):
    real = [frames(tmp_path / "moved" / "hop", c) for c in (1, 2)]
    saved = [[f"C:\\Users\\lab\\data\\hop\\cam{c}\\" + f.rsplit("/", 1)[1] for f in v]
             for c, v in zip((1, 2), real, strict=True)]
    p = make(tmp_path, views=saved)
    with pytest.raises(StudyError, match=r"hop_cam1\.0001\.tif not found"):
        import_xma(p, tmp_path / "s1")
    assert not (tmp_path / "s1").exists()
    with import_xma(p, tmp_path / "s2", search=[tmp_path / "moved"]) as st:
        view = st.manifest["trials"]["hop_1"]["views"][0]["path"]
        assert st.path(view) == tmp_path / "moved" / "hop" / "cam1"


def test_refusals_name_the_file_and_leave_nothing(tmp_path):
    p = make(tmp_path, flipped=True)
    with pytest.raises(StudyError, match=r"lab\.xma: camera 'cam1' is mirrored"):
        import_xma(p, tmp_path / "s")
    assert not (tmp_path / "s").exists()
    q = make(tmp_path / "b")
    (tmp_path / "full").mkdir()
    (tmp_path / "full" / "x").write_text("x")
    with pytest.raises(StudyError, match="not an empty folder"):
        import_xma(q, tmp_path / "full")
    assert [x.name for x in (tmp_path / "full").iterdir()] == ["x"]
    # a trial listing frames its folder does not hold exactly
    v = [frames(tmp_path / "c", c) for c in (1, 2)]
    r = make(tmp_path / "c", views=[v[0][:3], v[1][:3]])
    with pytest.raises(StudyError, match="holds 4 TIFF frames but the trial lists 3"):
        import_xma(r, tmp_path / "s3")
    bad = tmp_path / "bad.xma"
    bad.write_bytes(b"PK\x03\x04 not a zip")
    with pytest.raises(FileError, match=r"bad\.xma"):
        import_xma(bad, tmp_path / "s4")
    assert not (tmp_path / "s4").exists()


_n = itertools.count()
FUZZ = settings(max_examples=30, deadline=None, database=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])


@pytest.fixture(scope="module")
def good_project(tmp_path_factory):
    d = tmp_path_factory.mktemp("fz")
    p = make(d)
    with zipfile.ZipFile(p) as zf:
        return d, {n: zf.read(n) for n in zf.namelist()}


@FUZZ
@given(data=st.data())
def test_damaged_projects_are_refused_naming_the_file(good_project, data):
    """A damaged member of the project either imports or raises FileError naming the project (or
    the image it lists), and leaves no study behind."""
    from tests.core.io.test_xma_project_format import mutated

    d, members = good_project
    members = dict(members)
    name = data.draw(st.sampled_from(sorted(k for k in members if not k.endswith(".tif"))))
    members[name] = data.draw(mutated(members[name]))
    k = next(_n)
    p = d / f"f{k}.xma"
    with zipfile.ZipFile(p, "w") as zf:
        for m, v in members.items():
            zf.writestr(m, v)
    out = d / f"s{k}"
    try:
        import_xma(p, out).close()
    except FileError as exc:
        assert str(p) in str(exc) or "trial" in str(exc), str(exc)
        assert not out.exists()


def test_the_wrist_sample_as_an_xmalab_project(tmp_path, sample_data):
    """The real wrist radiographs (already undistorted by XMALab) and cameras, as an XMALab project
    saved on a Windows machine would list them: the study's rig is the sample's MayaCam rig and
    its trial the three frames, found through a search folder."""
    from core.geometry.mayacam import rig_from_mayacam

    data = sample_data / "autoscoper_wrist"
    if not data.is_dir():
        pytest.skip(reason=f"wrist sample not found at {data}")
    rig = rig_from_mayacam([data / "Calibration" / f"xr_calib_wrist_cam0{c}.txt" for c in (1, 2)])
    cams = [type(c)(K=c.K, R=c.R, t=c.t, width=c.width, height=c.height, name=f"camera{k + 1}")
            for k, c in enumerate(rig)]
    views = [[f"D:\\XROMM\\wrist\\xr_data_wrist_cam0{c}\\{p.name}"
              for p in sorted((data / "XMA_UND" / f"xr_data_wrist_cam0{c}").glob("*.tif"))] for c in (1, 2)]
    p = write_xma_project(tmp_path / "wrist.xma", cams, [XMATrialData("wrist", views, recording_speed=125.0)])
    with import_xma(p, tmp_path / "study", search=[data / "XMA_UND"]) as st:
        tr = st.trial("wrist")
        assert tr.n_frames == 3
        for a, b in zip(tr.rig(), rig, strict=True):
            np.testing.assert_allclose(a.K, b.K, atol=1e-9)
            np.testing.assert_allclose(a.R, b.R, atol=1e-12)
            np.testing.assert_allclose(a.t, b.t, atol=1e-9)
        assert [len(f.steps) for f in trial_correction(st, "wrist")] == [0, 0]  # nothing to undistort


def test_light_cameras_are_left_out(tmp_path):
    """A project with a light (video) camera beside the two X-ray ones: the study's calibration
    and trial have the X-ray cameras; the light camera's video need not be there."""
    from core.geometry.camera import Camera

    c1, c2 = cameras()
    light = Camera(K=c2.K, R=c2.R, t=c2.t, width=W, height=H, name="video")
    views = [frames(tmp_path / "raw", c) for c in (1, 2)] + [["/gone/video.avi"]]
    P = np.concatenate([markers()[0].points2d, markers()[0].points2d[:, :1]], axis=1)
    tr = XMATrialData("hop", views, [XMAMarkerData("bead", P)])
    p = write_xma_project(tmp_path / "three.xma", [c1, c2, light], [tr])
    with zipfile.ZipFile(p) as zf:
        m = {n: zf.read(n) for n in zf.namelist()}
    m["project.xml"] = m["project.xml"].replace(b'Name="video" isLightCamera="0"',
                                                b'Name="video" isLightCamera="1"')
    with zipfile.ZipFile(p, "w") as zf:
        for k, v in m.items():
            zf.writestr(k, v)
    with import_xma(p, tmp_path / "st") as st:
        assert [c.name for c in st.trial("hop").rig()] == ["cam1", "cam2"]
        assert st.settings["imported_from"]["light_cameras"] == ["video"]
        assert st.read_report("markers", "hop")["cameras"] == ["cam1", "cam2", "video"]


def test_trials_on_two_calibration_frames_get_two_calibrations(tmp_path):
    """A second trial referring to calibration frame 1 (the cube moved): a second calibration
    ``xmalab.v2`` with that frame's cameras."""
    from xml.etree import ElementTree

    from scipy.spatial.transform import Rotation

    views = [frames(tmp_path / "raw", c) for c in (1, 2)]
    tr = [XMATrialData(n, views) for n in ("a", "b")]
    p = write_xma_project(tmp_path / "two.xma", cameras(), tr)
    with zipfile.ZipFile(p) as zf:
        m = {n: zf.read(n) for n in zf.namelist()}
    root = ElementTree.fromstring(m["project.xml"])
    moved = Rotation.from_euler("z", 10, degrees=True).as_matrix()
    for cam, el in zip(cameras(), root.findall("Camera"), strict=True):
        img = ElementTree.SubElement(el, "CalibrationImage", Filename=f"{cam.name}/calib2.tif",
                                     isCalibrated="1")
        R2 = cam.R @ moved.T  # the lab turned by 10 degrees about z
        rows = "".join(", ".join(repr(float(v)) for v in r) + "\n" for r in R2)
        for tag, data in (("RotationMatrix", rows),
                          ("TranslationVector", "".join(f"{float(v)!r}\n" for v in cam.t))):
            member = f"{cam.name}/data/calib2_{tag}.csv"
            m[member] = data.encode()
            ElementTree.SubElement(img, tag, Filename=member)
    root.findall("Trial")[1].set("referenceCalibration", "1")
    m["project.xml"] = ElementTree.tostring(root)
    with zipfile.ZipFile(p, "w") as zf:
        for k, v in m.items():
            zf.writestr(k, v)
    with import_xma(p, tmp_path / "st") as st:
        assert st.calibrations == ("xmalab.v1", "xmalab.v2")
        assert [st.manifest["trials"][t]["calibration"] for t in ("a", "b")] == ["xmalab.v1", "xmalab.v2"]
        np.testing.assert_allclose(st.trial("b").rig()[0].R, cameras()[0].R @ moved.T, atol=1e-12)
        assert st.settings["calibration_files"]["xmalab.v2"]["reference_frame"] == 1
