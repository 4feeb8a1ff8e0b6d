"""Bad input to a session calibration saved into a study (issue 16, "Bad input"): a missing view,
frames of different sizes, a grid frame without a grid, too few labelled frames, a bundle
adjustment that does not converge, a static cube frame that cannot be labelled. Each error names
the step, the file (and frame) and what can be done, and the study is left unchanged. A session
without a static object frame calibrates with a warning that the lab frame is not the cube's.

The session is the calibration tests' small one (conftest: 384², 10 spiral frames, the static cube,
1 grid frame per camera) written as a folder; the cases that need its labelled beads reuse the
beads step the other calibration tests share (the same frames: labelling them again here would
double the cost).
"""

import dataclasses
import json
import shutil

import numpy as np
import pytest
import tifffile

from core.calibration import session as cs
from core.calibration.bundle import _failure
from core.calibration.matching import FrameLabels
from core.errors import FileError
from core.io.calibration_session import read_session
from core.study import Study
from core.study.calibrations import calibrate_study


@pytest.fixture(scope="module")
def session_dir(memory_session_dir):
    return memory_session_dir


@pytest.fixture(scope="module")
def beads(memory_session_dir_beads):
    """The labelled beads of the good session (the expensive step, shared)."""
    out = memory_session_dir_beads
    assert sum(f.ok for f in out.frames) >= cs.MIN_LABELLED_FRAMES and out.static_frames[0].ok
    return out


@pytest.fixture
def study(tmp_path):
    Study.create(tmp_path / "study").close()
    return tmp_path / "study"


def _state(folder):
    """Everything in the study folder: file names and bytes."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def _calibrate(study, session):
    before = _state(study)
    with Study.open(study, mode="w") as st, pytest.raises((cs.SessionError, FileError)) as e:
        calibrate_study(st, session)
    assert _state(study) == before  # nothing saved
    return e.value


def _copy(session_dir, tmp_path):
    out = tmp_path / "session"
    shutil.copytree(session_dir, out)
    return out


def _use_beads(monkeypatch, beads):
    monkeypatch.setattr(cs, "beads_step", lambda setup, dist, **kw: beads)


# ---------------------------------------------------------------------------- the cases
def test_missing_view(session_dir, study, tmp_path):
    s = _copy(session_dir, tmp_path)
    shutil.rmtree(s / "cam2" / "spiral")
    e = _calibrate(study, s)
    msg = str(e)
    assert isinstance(e, FileError) and "cam2/spiral: missing spiral group folder of view 'cam2'" in msg
    assert "record or copy the view's spiral frames into it" in msg
    shutil.rmtree(s / "cam2")
    assert "copy the view's frames into it" in str(_calibrate(study, s))


def test_one_camera_in_the_manifest(session_dir, study, tmp_path):
    s = _copy(session_dir, tmp_path)
    man = json.loads((s / "session.json").read_text())
    man["cameras"] = ["cam1"]
    (s / "session.json").write_text(json.dumps(man))
    e = _calibrate(study, s)
    assert isinstance(e, cs.SessionError) and e.step == "session" and e.where == "cameras"
    assert "expected the 2 cameras of a biplane rig" in str(e) and "camera list" in e.hint


def test_frames_of_different_sizes(session_dir, study, tmp_path):
    s = _copy(session_dir, tmp_path)
    f = s / "cam1" / "grid" / "0000.tif"
    tifffile.imwrite(f, tifffile.imread(f)[:-8])
    e = _calibrate(study, s)
    assert isinstance(e, FileError) and str(e).startswith(str(f))
    assert "frame of 376x384 (H x W); expected 384x384" in str(e) and "full resolution" in str(e)


def test_frames_of_different_sizes_read_by_a_step(session_dir):
    """A session object that does not check sizes itself: the step that reads the frame says it."""
    s = read_session(session_dir)
    first = s.frames("cam2", "grid")[0]

    class Cropped:
        cameras, manifest, kvs = s.cameras, s.manifest, s.kvs

        def frames(self, cam, group):
            return s.frames(cam, group)

        def read(self, ref):
            img = s.read(ref)
            return img[:, :-4] if ref == first else img

    setup = cs.prepare(Cropped())
    ffs = cs.flatfield_step(setup)
    where = r"grid/0000.tif \(frame 0\): frame of 380x384 pixels, but"
    with pytest.raises(cs.SessionError, match=where) as e:
        cs.distortion_step(setup, ffs)
    assert e.value.step == "distortion" and "one size" in e.value.hint


def test_grid_frame_without_grid(session_dir, study, tmp_path):
    s = _copy(session_dir, tmp_path)
    shutil.copy(s / "cam2" / "flat_70kV" / "0000.tif", s / "cam2" / "grid" / "0000.tif")
    e = _calibrate(study, s)
    assert e.step == "distortion" and "cam2/grid/0000.tif (grid frame 0 of camera cam2)" in e.where
    assert "no distortion grid found" in e.what and "remove the frame" in e.hint


def test_too_few_labelled_frames(session_dir, study, tmp_path):
    s = _copy(session_dir, tmp_path)
    man = json.loads((s / "session.json").read_text())
    for cam in man["cameras"]:
        for f in sorted((s / cam / "spiral").iterdir())[3:]:
            f.unlink()
    man["n_frames"]["spiral"] = 3
    (s / "session.json").write_text(json.dumps(man))
    e = _calibrate(study, s)
    assert e.step == "beads" and e.where.startswith("spiral33 frames") and "record more frames" in e.hint
    # some labelled (fewer than the bundle needs), or none (the epipolar geometry cannot be estimated:
    # the case of these 3 frames)
    assert "of 3 frames could be labelled in both views" in e.what or (
        "no frame could be labelled in both views" in e.what and "cam1/spiral/0000.tif to " in e.where)


def test_too_few_labelled_frames_names_them(session_dir, study, beads, monkeypatch):
    bad = dataclasses.replace(beads, frames=[
        FrameLabels(f.labellings, f.ok and k >= 7, "" if k >= 7 else "fewer than 6 labelled beads in a view",
                    f.distance_px) for k, f in enumerate(beads.frames)])
    _use_beads(monkeypatch, bad)
    e = _calibrate(study, session_dir)
    assert e.step == "beads" and f"only {sum(f.ok for f in bad.frames)} of {len(bad.frames)} frames" in e.what
    assert "cam1/spiral/0000.tif (frame 0): fewer than 6 labelled beads in a view" in e.what


def test_bundle_not_converging(session_dir, study, beads, monkeypatch):
    _use_beads(monkeypatch, beads)
    monkeypatch.setattr(cs, "bundle_adjust", lambda frames, sizes, **kw: _failure(
        "the optimizer did not converge (max evaluations)", len(sizes), len(frames)))
    e = _calibrate(study, session_dir)
    n = sum(f.ok for f in beads.frames) + 1
    assert e.step == "bundle" and e.where == f"{n} labelled frames (spiral33 + cube15)"
    assert "did not converge" in e.what and "remove frames with wrong labels" in e.hint


def test_unlabelled_cube_is_an_error(session_dir, study, beads, monkeypatch):
    fr = beads.static_frames[0]
    bad = dataclasses.replace(beads, static_frames=[FrameLabels(fr.labellings, False, "no consistent "
                                                                "labelling", fr.distance_px)])
    _use_beads(monkeypatch, bad)
    e = _calibrate(study, session_dir)
    assert e.step == "beads" and e.where.endswith("cam1/cube/0000.tif (cube15 frame 0)")
    assert "could not be labelled (no consistent labelling); it defines the lab frame" in e.what
    assert "--lab-frame object" in e.hint


def test_no_cube_calibrates_with_a_warning(session_dir, study, beads, monkeypatch):
    no_cube = dataclasses.replace(beads, static_frames=[], static_detections=[], static_refs=[])
    _use_beads(monkeypatch, no_cube)
    with Study.open(study, mode="w") as st:
        saved, cal = calibrate_study(st, session_dir)
    assert cal.report["lab_frame"]["defined_by"] == "object" and cal.static_target is None
    (w,) = cal.report["warnings"]
    assert "no static cube15 frame: the lab frame is the spiral33's first labelled frame" in w
    rep = json.loads((saved.folder / "report" / "report.json").read_text())
    assert rep["warnings"] == [w]


def test_lab_frame_object_when_asked(session_dir, beads, monkeypatch):
    _use_beads(monkeypatch, beads)
    cal = cs.calibrate_session(read_session(session_dir), lab_frame="object")
    first = [str(session_dir / cam / "spiral" / "0000.tif") for cam in ("cam1", "cam2")]
    assert cal.report["lab_frame"] == {"defined_by": "object", "object": "spiral33", "frame": first}
    assert "not the static cube15's" in cal.report["warnings"][0]
    cube = [r for r in cal.frames if r["group"] == "cube"]
    assert len(cube) == 1 and not cube[0]["ok"] and "not used" in cube[0]["reason"]
    ref = cal.bundle.object_poses[0]  # the lab is the spiral's first labelled frame
    assert np.allclose(ref, np.eye(4), atol=1e-9)
    with pytest.raises(ValueError, match="lab_frame: expected one of"):
        cs.calibrate_session(read_session(session_dir), lab_frame="cube")
